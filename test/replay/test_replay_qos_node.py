"""The replay node over real DDS: it offers each topic with the recorded publishers'
reliability (or the one the ``qos`` parameter forces), and ``until_topic`` ends a loop at
the end of the pass during which a CameraInfo arrived, latched or not."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image

from test.integration.qos import LATCHED
from test.integration.ros_harness import NodeProcess, Probe, wait_until
from test.replay.test_recorded_qos import offer

pytestmark = pytest.mark.replay

T0 = 1_700_000_000_000_000_000  # ns
PERIOD_NS = 50_000_000
N_IMAGES = 3
BEST_EFFORT_ALL = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                             reliability=ReliabilityPolicy.BEST_EFFORT)
RELIABLE_ALL = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                          reliability=ReliabilityPolicy.RELIABLE)


def image_bag(path: Path, offers: dict[str, list[Any]]) -> Path:
    """A rosbag2 directory (rosbags library) with N_IMAGES 2x1 mono8 images per topic, the
    images' pixels equal to their index; each topic recorded with ``offers``."""
    import numpy as np
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_KILTED)
    RImage = ts.types["sensor_msgs/msg/Image"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = [w.add_connection(topic, RImage.__msgtype__, typestore=ts,
                                  offered_qos_profiles=profiles)
                 for topic, profiles in offers.items()]
        for k in range(N_IMAGES):
            t = T0 + k * PERIOD_NS
            msg = RImage(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9),
                                       frame_id="cam"),
                         height=1, width=2, encoding="mono8", is_bigendian=0, step=2,
                         data=np.full(2, k, dtype=np.uint8))
            for conn in conns:
                w.write(conn, t, ts.serialize_cdr(msg, RImage.__msgtype__))
    return path


def replay(tmp_path: Path, bag: Path, *params: str) -> NodeProcess:
    args = ["-p", f"bag:={bag}", "-p", "wait_timeout:=30.0"]
    for p in params:
        args += ["-p", p]
    return NodeProcess("replay", args, tmp_path)


def offered_reliability(probe: Probe, topic: str) -> ReliabilityPolicy:
    """The reliability the one publisher of ``topic`` offers (waits for it to appear)."""
    infos = wait_until(lambda: probe.node.get_publishers_info_by_topic(topic), 30,
                       f"a publisher on {topic}")
    assert len(infos) == 1, infos
    return infos[0].qos_profile.reliability


def stop_cleanly(node: NodeProcess) -> None:
    rc = node.stop()
    assert rc in (0, -2, 130), node.output()
    assert "Traceback" not in node.output(), node.output()


@pytest.mark.parametrize(("qos", "expected"), [
    ("recorded", {"be": ReliabilityPolicy.BEST_EFFORT, "rel": ReliabilityPolicy.RELIABLE}),
    ("reliable", {"be": ReliabilityPolicy.RELIABLE, "rel": ReliabilityPolicy.RELIABLE}),
    ("best_effort", {"be": ReliabilityPolicy.BEST_EFFORT, "rel": ReliabilityPolicy.BEST_EFFORT}),
])
def test_topics_are_offered_as_recorded_or_as_the_qos_parameter_says(
        tmp_path: Path, probe: Probe, qos: str, expected: dict[str, ReliabilityPolicy]) -> None:
    prefix = f"/qos_{qos}"
    bag = image_bag(tmp_path / "bag", {f"{prefix}/be": [offer("best_effort")],
                                       f"{prefix}/rel": [offer("reliable")]})
    # best-effort subscribers match either kind of publisher
    received = {name: probe.collect(Image, f"{prefix}/{name}", BEST_EFFORT_ALL)
                for name in expected}
    node = replay(tmp_path, bag, "rate:=1.0", "loop:=true", f"qos:={qos}")
    try:
        for name, reliability in expected.items():
            assert offered_reliability(probe, f"{prefix}/{name}") == reliability
        wait_until(lambda: all(received.values()), 30, "images on both topics")
    finally:
        stop_cleanly(node)
    assert f"{prefix}/be (" + ("best_effort" if qos != "reliable" else "reliable") \
        in node.output()


def test_a_best_effort_recording_reaches_no_reliable_subscriber(
        tmp_path: Path, probe: Probe) -> None:
    """The offer is real: DDS refuses a reliable subscriber a best-effort publisher (as it
    would the recorded camera), and the same subscriber gets every frame once forced."""
    bag = image_bag(tmp_path / "bag", {"/qos_match/image": [offer("best_effort")]})
    reliable = probe.collect(Image, "/qos_match/image", RELIABLE_ALL)
    node = replay(tmp_path, bag, "rate:=0.0", "wait_timeout:=3.0")
    assert node.wait(60) == 0, node.output()
    assert reliable == []
    forced = replay(tmp_path, bag, "rate:=0.0", "qos:=reliable")
    assert forced.wait(60) == 0, forced.output()
    wait_until(lambda: len(reliable) == N_IMAGES, 10, "every image, reliably")


def test_until_topic_ends_the_loop_after_the_pass_a_camera_info_came_in(
        tmp_path: Path, probe: Probe) -> None:
    bag = image_bag(tmp_path / "bag", {"/until/image": [offer("reliable")]})
    images = probe.collect(Image, "/until/image", RELIABLE_ALL)
    info_pub = probe.node.create_publisher(CameraInfo, "/until/camera_info", LATCHED)
    try:
        node = replay(tmp_path, bag, "rate:=1.0", "loop:=true",
                      "until_topic:=/until/camera_info")
        wait_until(lambda: len(images) >= 2 * N_IMAGES, 30, "two passes of the bag")
        info_pub.publish(CameraInfo(width=640, height=480))
        assert node.wait(30) == 0, node.output()
    finally:
        probe.node.destroy_publisher(info_pub)
    text = node.output()
    assert "a message came on /until/camera_info: stopping after" in text, text
    # every pass ends complete: the images received are whole passes
    wait_until(lambda: len(images) % N_IMAGES == 0, 5, "the last pass complete")
    assert [int(m.data[0]) for m in images[:N_IMAGES]] == list(range(N_IMAGES))
    assert "Traceback" not in text


def test_until_topic_sees_a_result_latched_before_the_replay_started(
        tmp_path: Path, probe: Probe) -> None:
    bag = image_bag(tmp_path / "bag", {"/latched/image": [offer("reliable")]})
    images = probe.collect(Image, "/latched/image", RELIABLE_ALL)
    info_pub = probe.node.create_publisher(CameraInfo, "/latched/camera_info", LATCHED)
    info_pub.publish(CameraInfo(width=640, height=480))
    try:
        node = replay(tmp_path, bag, "rate:=1.0", "loop:=true",
                      "until_topic:=/latched/camera_info")
        assert node.wait(30) == 0, node.output()
    finally:
        probe.node.destroy_publisher(info_pub)
    assert "stopping after" in node.output(), node.output()
    wait_until(lambda: len(images) >= N_IMAGES, 5, "the passes played")
