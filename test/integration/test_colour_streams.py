"""Colour cameras through the real calibrator node, from reliable and best-effort publishers.

A colour camera's VGA frames are 614 kB (``yuv422``) to 921 kB (``bgr8``, ``rgb8``), more
than Fast DDS's default shared-memory segment: the node must still receive and track them.

- ``bags/sample_color`` (40 ``bgr8`` frames, 40 poses, 10 Hz) replayed once at rate 1.0
  right after the node starts, the recording's reliable QoS or forced best effort: at least
  36 frames tracked, at least 10 views, and ``~/calibrate`` succeeds.
- ``rgb8`` and ``yuv422`` frames, and JPEG ``CompressedImage`` (``image_transport:
  compressed``), 20 of each replayed once at 10 Hz from bags the test writes: the node
  counts them seen and processed and publishes their overlays.

The replay stands in for the camera driver, with the large shared-memory segment the README
tells a driver to use.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from artcal_ros.bag import BagReader, BagWriter
from artcal_ros.core.images import image_to_numpy, numpy_to_image
from test.integration.qos import RELIABLE
from test.integration.ros_harness import (
    ROOT,
    NodeProcess,
    Probe,
    calibrator_node,
    diagnostics_values,
    wait_until,
)

pytestmark = pytest.mark.integration

COLOUR_BAG = ROOT / "bags" / "sample_color"
COLOUR_TOPIC = "/camera/image_raw"
BAG_FRAMES = 40
MIN_TRACKED = 36  # issue 20: of the 40 frames replayed once
MIN_VIEWS = 10  # config/calibrator.yaml
KINDS = ("reliable", "best_effort")  # the publisher's QoS, the replay's qos parameter
BATCH = 20  # frames of each encoding, played at the camera's 10 Hz
# Reliable delivery loses nothing; the node keeps only the newest frame, and at 10 Hz it
# takes each before the next arrives. Best effort may lose frames in transport, but a
# camera whose frames mostly vanish is what the node must not accept.
MIN_SHARE = {"reliable": 0.95, "best_effort": 0.8}
COUNTS = ("frames processed", "frames dropped (busy)", "frames broken", "frames failed")


@pytest.fixture(scope="module")
def colour_frames() -> list[np.ndarray]:
    """The first BATCH frames of the colour bag: (480, 640, 3) BGR uint8 each."""
    from rclpy.serialization import deserialize_message

    frames = []
    with BagReader(COLOUR_BAG) as r:
        for m in r.messages([COLOUR_TOPIC]):
            frames.append(image_to_numpy(deserialize_message(m.data, Image)))
            if len(frames) == BATCH:
                break
    assert frames[0].shape == (480, 640, 3)
    return frames


def stamp(k: int) -> int:
    """The time stamp of frame ``k`` of a 10 Hz stream, ns."""
    return 1_700_000_000_000_000_000 + k * 100_000_000


def frames_bag(path: Path, frames: list[np.ndarray], encoding: str) -> Path:
    """A rosbag2 directory of ``frames`` at 10 Hz on COLOUR_TOPIC as sensor_msgs/Image in
    ``encoding``, or, for ``jpeg``, on COLOUR_TOPIC/compressed as image_transport's
    compressed plugin sends a bgr8 camera."""
    with BagWriter(path) as w:
        for k, bgr in enumerate(frames):
            t = stamp(k)
            if encoding == "jpeg":
                ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 90])
                assert ok
                w.write(f"{COLOUR_TOPIC}/compressed", "sensor_msgs/msg/CompressedImage", t, {
                    "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9},
                               "frame_id": "camera"},
                    "format": "bgr8; jpeg compressed bgr8", "data": buf.tobytes()})
            else:
                w.write(COLOUR_TOPIC, "sensor_msgs/msg/Image", t,
                        numpy_to_image(bgr, encoding, t, "camera"))
    return path


class NodeCounts:
    """A node's counters, read from its newest /diagnostics report."""

    def __init__(self, diagnostics: list[Any], name: str) -> None:
        self.diagnostics = diagnostics
        self.name = name

    def values(self) -> dict[str, str]:
        return diagnostics_values(self.diagnostics, self.name)

    def get(self, key: str) -> int:
        return int(self.values().get(key, 0))

    def accounted(self) -> dict[str, str] | None:
        """The values once every frame seen is processed, dropped, broken or failed."""
        v = self.values()
        if not v:
            return None
        return v if sum(int(v[k]) for k in COUNTS) == int(v["frames seen"]) else None


def play_into(tmp_path: Path, bag: Path, topic: str, kind: str, counts: NodeCounts,
              overlays: list[Any], what: str, frames: int) -> None:
    """Replay ``bag`` once at its 10 Hz into the node at ``topic``, offered ``kind``; the
    node must see and process at least MIN_SHARE[kind] of its ``frames`` and publish
    overlays."""
    values = wait_until(counts.accounted, 60, f"{counts.name} up and idle")
    seen0, processed0 = int(values["frames seen"]), int(values["frames processed"])
    overlays0 = len(overlays)
    replay = NodeProcess("replay", ["-p", f"bag:={bag}", "-p", "rate:=1.0", "-p", f"qos:={kind}",
                                    "-r", f"{COLOUR_TOPIC}:={topic}",
                                    "-r", f"{COLOUR_TOPIC}/compressed:={topic}/compressed"],
                         tmp_path, name=f"replay_{what}_{kind}")
    assert replay.wait(90) == 0, replay.output()
    # The replay has ended: wait for all of them, or until no more arrive (the count has
    # held through three diagnostics reports), however slowly a loaded machine delivers.
    seen, held_since = counts.get("frames seen"), time.monotonic()
    while seen - seen0 < frames and time.monotonic() - held_since < 3.5:
        time.sleep(0.2)
        if counts.get("frames seen") != seen:
            seen, held_since = counts.get("frames seen"), time.monotonic()
    values = wait_until(counts.accounted, 30, f"{counts.name} done with the {what} frames")
    seen = int(values["frames seen"]) - seen0
    processed = int(values["frames processed"]) - processed0
    need = math.ceil(MIN_SHARE[kind] * frames)
    assert seen >= need and processed >= need, (
        f"{what} ({kind}): the node saw {seen} and processed {processed} of {frames} "
        f"frames (need {need}); {values}")
    assert int(values["frames broken"]) == 0, values
    assert len(overlays) > overlays0, f"no overlay for the {what} frames"


@pytest.mark.parametrize("kind", KINDS)
def test_colour_bag_replayed_once_after_the_node_starts_calibrates(
        tmp_path: Path, probe: Probe, kind: str) -> None:
    name = f"cal_colour_{kind}"
    topic = f"/{name}/image"
    overlays = probe.collect(Image, f"/{name}/overlay", RELIABLE)
    counts = NodeCounts(probe.collect(DiagnosticArray, "/diagnostics", RELIABLE), name)
    node = calibrator_node(tmp_path, name, image_topic=topic)
    # Started at once: it waits for the node's subscription, then plays the 4 s once.
    replay = NodeProcess("replay", [
        "-p", f"bag:={COLOUR_BAG}", "-p", "rate:=1.0",
        "-p", f"qos:={'recorded' if kind == 'reliable' else kind}",
        "-r", f"{COLOUR_TOPIC}:={topic}"], tmp_path, name=f"replay_{kind}")
    assert replay.wait(120) == 0, replay.output()
    assert f"{topic} ({kind}" in replay.output(), replay.output()
    values = wait_until(counts.accounted, 60, f"{name} done with the frames it received")
    assert int(values["frames processed"]) >= MIN_TRACKED, (
        f"{values['frames processed']} of {BAG_FRAMES} frames tracked; {values}")
    assert int(values["frames broken"]) == 0, values
    assert overlays and (overlays[0].width, overlays[0].height) == (640, 480)
    # Views come from the precise tier, which may still be working through its queue.
    try:
        wait_until(lambda: counts.get("views") >= MIN_VIEWS, 60, f"{MIN_VIEWS} views")
    except AssertionError as e:
        raise AssertionError(f"{e}; {counts.values()}") from None
    answer = probe.call(Trigger, f"/{name}/calibrate", timeout=120)
    assert answer.success, f"{answer.message}\n{node.tail(20)}"


@pytest.mark.parametrize("kind", KINDS)
def test_rgb8_yuv422_and_jpeg_frames_reach_the_node(
        tmp_path: Path, probe: Probe, colour_frames: list[np.ndarray], kind: str) -> None:
    raw_name, jpeg_name = f"cal_raw_{kind}", f"cal_jpeg_{kind}"
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    raw_overlays = probe.collect(Image, f"/{raw_name}/overlay", RELIABLE)
    jpeg_overlays = probe.collect(Image, f"/{jpeg_name}/overlay", RELIABLE)
    calibrator_node(tmp_path, raw_name, image_topic=f"/{raw_name}/image")
    calibrator_node(tmp_path, jpeg_name, "image_transport:=compressed",
                    image_topic=f"/{jpeg_name}/image")
    for encoding in ("rgb8", "yuv422"):
        bag = frames_bag(tmp_path / encoding, colour_frames, encoding)
        play_into(tmp_path, bag, f"/{raw_name}/image", kind, NodeCounts(diagnostics, raw_name),
                  raw_overlays, encoding, len(colour_frames))
    bag = frames_bag(tmp_path / "jpeg", colour_frames, "jpeg")
    play_into(tmp_path, bag, f"/{jpeg_name}/image", kind, NodeCounts(diagnostics, jpeg_name),
              jpeg_overlays, "jpeg", len(colour_frames))
