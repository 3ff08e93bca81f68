"""The calibrator's image QoS follows the publishers, and a reliable colour stream arrives whole.

A 640x480 bgr8 frame (921 kB) is larger than Fast DDS's default shared-memory segment: a
best-effort subscription to a reliable camera loses most such frames. With ``image_qos: auto``
the node subscribes reliable to a reliable publisher (every frame arrives), best effort as
soon as a best-effort publisher is there, and says which in its diagnostics; every frame the
publisher sent is either seen or counted as missed from the publication sequence numbers.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import cv2
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image

from artcal_ros.core.images import image_to_numpy, numpy_to_image
from artcal_ros.ros.image_subscription import choose_qos
from test.integration.frames import CalibrationBag, image_messages
from test.integration.qos import RELIABLE
from test.integration.ros_harness import calibrator_node, diagnostics_values, wait_until
from test.integration.streaming import publish_until

NODE = "cal_qos"
FRAMES = 30
RATE_HZ = 10.0


def _camera_qos(reliable: bool) -> QoSProfile:
    # A camera driver's publisher: keep last 5 as ROS's sensor-data profile.
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                      reliability=ReliabilityPolicy.RELIABLE if reliable
                      else ReliabilityPolicy.BEST_EFFORT)


def _bgr8_frames(bag: CalibrationBag, n: int) -> list[Any]:
    """``n`` of the bag's frames as 640x480 bgr8 messages (a colour camera's)."""
    out = []
    for msg in image_messages(bag)[:n]:
        grey = image_to_numpy(msg)
        fields = numpy_to_image(cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR), encoding="bgr8")
        out.append(Image(header=msg.header, height=fields["height"], width=fields["width"],
                         encoding="bgr8", is_bigendian=0, step=fields["step"],
                         data=fields["data"]))
    return out


def test_choice_follows_every_publisher() -> None:
    assert choose_qos("auto", [True, True]).reliable
    assert not choose_qos("auto", [True, False]).reliable
    assert not choose_qos("auto", []).reliable
    assert choose_qos("reliable", [False]).reliable
    assert not choose_qos("best_effort", [True]).reliable
    assert "1 of 2" in choose_qos("auto", [False, True]).reason


def test_auto_qos_takes_every_reliable_colour_frame_then_follows_a_best_effort_publisher(
        tmp_path: Path, probe: Any, bag: CalibrationBag) -> None:
    frames = _bgr8_frames(bag, FRAMES)
    assert len(frames[0].data) == 640 * 480 * 3
    node = calibrator_node(tmp_path, NODE)
    diagnostics: list[DiagnosticArray] = probe.collect(DiagnosticArray, "/diagnostics",
                                                       RELIABLE)

    def values() -> dict[str, str]:
        return diagnostics_values(diagnostics, NODE)

    def count(key: str) -> int:
        value = values().get(key, "")
        return int(value) if value.isdigit() else 0

    topic = f"/{NODE}/image"
    reliable = probe.node.create_publisher(Image, topic, _camera_qos(True))
    try:
        wait_until(lambda: reliable.get_subscription_count() > 0, 60, "the node's subscription")
        wait_until(lambda: values().get("image qos", "").startswith("reliable"), 60,
                   "image qos to turn reliable for a reliable publisher")
        # One frame first, until it is seen: the node may not have matched the publisher
        # yet when the publisher already sees the node.
        publish_until(reliable, frames[0], lambda: count("frames seen") >= 1, 60,
                      "the first reliable frame")
        seen_before = count("frames seen")
        for msg in frames:
            reliable.publish(msg)
            time.sleep(1.0 / RATE_HZ)
        wait_until(lambda: count("frames seen") - seen_before
                   + count("frames missed (publisher sequence)") >= FRAMES, 60,
                   "every frame to be seen or counted as missed")
        seen = count("frames seen") - seen_before
        missed = count("frames missed (publisher sequence)")
        assert seen + missed == FRAMES, values()
        # Reliable delivery: lost fragments are sent again, so frames are missed only when
        # the node's callback fell behind the stream.
        assert seen >= 0.8 * FRAMES, values()
        assert "frames missed (publisher sequence)" in values()
    finally:
        probe.node.destroy_publisher(reliable)

    best_effort = probe.node.create_publisher(Image, topic, _camera_qos(False))
    try:
        wait_until(lambda: values().get("image qos", "").startswith("best effort"), 60,
                   "image qos to turn best effort for a best-effort publisher")
        seen_before = count("frames seen")
        # A mono8 frame (307 kB): it fits the probe's default shared-memory segment, so a
        # best-effort frame arrives whole without many tries (a 921 kB bgr8 one from this
        # probe goes by UDP fragments, and best effort loses most of those).
        publish_until(best_effort, image_messages(bag)[1], lambda: count("frames seen")
                      > seen_before, 60, "a best-effort frame to arrive", every_s=0.5)
        assert "auto" in values()["image qos"], values()
        assert values()["dds transport"].startswith("64 MB shared memory"), values()
    finally:
        probe.node.destroy_publisher(best_effort)
    rc = node.stop()
    log = node.output()
    assert rc in (0, -2, 130), f"exit {rc}\n{log[-3000:]}"
    assert "image qos: reliable" in log and "image qos: best effort" in log, log


@pytest.mark.parametrize("mode", ["reliable", "best_effort"])
def test_forced_qos_is_reported(tmp_path: Path, probe: Any, mode: str) -> None:
    name = f"cal_qos_{mode}"
    node = calibrator_node(tmp_path, name, f"image_qos:={mode}")
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    text = wait_until(lambda: diagnostics_values(diagnostics, name).get("image qos"), 60,
                      "the node's diagnostics")
    assert text == f"{mode.replace('_', ' ')} (image_qos: {mode})", text
    # A best-effort camera: a forced reliable subscription cannot match it, and says so.
    best_effort = probe.node.create_publisher(Image, f"/{name}/image", _camera_qos(False))
    try:
        if mode == "reliable":
            wait_until(lambda: "1 publisher(s) of /cal_qos_reliable/image offer best effort"
                       in node.output(), 60, "the unmatched publisher's warning")
        else:
            wait_until(lambda: best_effort.get_subscription_count() > 0, 60,
                       "the best-effort subscription to match")
            assert "offer best effort" not in node.output()
    finally:
        probe.node.destroy_publisher(best_effort)
    assert node.stop() in (0, -2, 130), node.output()[-3000:]
