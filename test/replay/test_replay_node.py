"""The replay node over real DDS: bags written by an independent writer (rosbags) and by
BagWriter, timing scaled by ``rate``, topic filter, remap, start offset, loop, damaged bags
and bad parameters."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import pytest
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from std_msgs.msg import String

from artcal_ros.bag import BagWriter
from test.integration.ros_harness import NodeProcess, Probe, wait_until

pytestmark = pytest.mark.replay

RELIABLE_ALL = QoSProfile(history=HistoryPolicy.KEEP_ALL,
                          reliability=ReliabilityPolicy.RELIABLE)
T0 = 1_700_000_000_000_000_000  # ns
PERIOD_NS = 200_000_000  # 0.2 s between recorded images
N_IMAGES = 6


def rosbags_bag(path: Path, prefix: str) -> Path:
    """A rosbag2 directory written by the rosbags library (as `ros2 bag record -s mcap` does):
    N_IMAGES 4x3 mono8 images whose pixels all equal their index, and 3 strings."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_KILTED)
    RImage = ts.types["sensor_msgs/msg/Image"]
    RString = ts.types["std_msgs/msg/String"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    import numpy as np

    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        img = w.add_connection(f"{prefix}/image_raw", RImage.__msgtype__, typestore=ts)
        txt = w.add_connection(f"{prefix}/chatter", RString.__msgtype__, typestore=ts)
        for k in range(N_IMAGES):
            t = T0 + k * PERIOD_NS
            msg = RImage(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9),
                                       frame_id="cam"),
                         height=3, width=4, encoding="mono8", is_bigendian=0, step=4,
                         data=np.full(12, k, dtype=np.uint8))
            w.write(img, t, ts.serialize_cdr(msg, RImage.__msgtype__))
            if k % 2 == 0:
                w.write(txt, t + 1, ts.serialize_cdr(RString(data=f"hello {k}"),
                                                     RString.__msgtype__))
    return path


def received_indices(images: list[Any]) -> list[int]:
    return [int(m.data[0]) for m in images]


def replay(tmp_path: Path, bag: Path, *params: str) -> NodeProcess:
    args = ["-p", f"bag:={bag}", "-p", "wait_timeout:=30.0"]
    for p in params:
        args += ["-p", p]
    return NodeProcess("replay", args, tmp_path)


def assert_clean(text: str) -> None:
    assert "Traceback" not in text, text


def test_plays_an_independently_written_bag_in_order(tmp_path: Path, probe: Probe) -> None:
    bag = rosbags_bag(tmp_path / "bag", "/t1")
    images = probe.collect(Image, "/t1/image_raw", RELIABLE_ALL)
    texts = probe.collect(String, "/t1/chatter", RELIABLE_ALL)
    node = replay(tmp_path, bag, "rate:=0.0")
    assert node.wait(60) == 0, node.output()
    assert received_indices(images) == list(range(N_IMAGES))
    assert [m.data for m in texts] == ["hello 0", "hello 2", "hello 4"]
    first = images[0]
    assert (first.width, first.height, first.encoding, first.header.frame_id) == \
        (4, 3, "mono8", "cam")
    assert first.header.stamp.sec == T0 // 10**9
    assert f"played {N_IMAGES + 3} messages" in node.output()
    assert_clean(node.output())


def test_rate_scales_the_recorded_timing(tmp_path: Path, probe: Probe) -> None:
    bag = rosbags_bag(tmp_path / "bag", "/t2")
    arrivals: list[float] = []
    probe.node.create_subscription(Image, "/t2/image_raw",
                                   lambda _m: arrivals.append(time.monotonic()), RELIABLE_ALL)
    node = replay(tmp_path, bag, "rate:=2.0", "topics:=['/t2/image_raw']")
    assert node.wait(60) == 0, node.output()
    assert len(arrivals) == N_IMAGES
    span = arrivals[-1] - arrivals[0]
    recorded = (N_IMAGES - 1) * PERIOD_NS * 1e-9  # 1.0 s
    # At rate 2 the 1.0 s recording takes 0.5 s. The player never runs early, so only
    # delivery jitter of the first message can shorten it; a loaded 2-core machine can
    # stretch it, but not anywhere near the 1.0 s of rate 1.
    assert 0.45 <= span <= 0.8, f"span {span:.3f} s for {recorded} s recorded at rate 2"


def test_topic_filter_remap_and_start_offset(tmp_path: Path, probe: Probe) -> None:
    bag = rosbags_bag(tmp_path / "bag", "/t3")
    remapped = probe.collect(Image, "/t3/renamed", RELIABLE_ALL)
    original = probe.collect(Image, "/t3/image_raw", RELIABLE_ALL)
    texts = probe.collect(String, "/t3/chatter", RELIABLE_ALL)
    node = replay(tmp_path, bag, "rate:=0.0", "topics:=['/t3/image_raw']",
                  "remap:=['/t3/image_raw:=/t3/renamed']", "start_offset:=0.5")
    assert node.wait(60) == 0, node.output()
    # Recorded at 0.0, 0.2, ... 1.0 s: skipping 0.5 s leaves 0.6, 0.8 and 1.0 s.
    assert received_indices(remapped) == [3, 4, 5]
    assert original == [] and texts == []


def test_bare_mcap_file_loops_until_sigint(tmp_path: Path, probe: Probe) -> None:
    path = tmp_path / "one.mcap"
    with BagWriter(path, storage="mcap") as w:
        for k in range(3):
            t = T0 + k * 10_000_000
            w.write("/t4/image_raw", "sensor_msgs/msg/Image", t, {
                "header": {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9},
                           "frame_id": "cam"},
                "height": 1, "width": 2, "encoding": "mono8", "is_bigendian": 0, "step": 2,
                "data": bytes([k, k])})
    images = probe.collect(Image, "/t4/image_raw", RELIABLE_ALL)
    node = replay(tmp_path, path, "rate:=1.0", "loop:=true")
    wait_until(lambda: len(images) >= 9, 30, "three loops of the bag")
    rc = node.stop()
    assert rc in (0, -2, 130), node.output()
    assert received_indices(images[:6]) == [0, 1, 2] * 2
    assert_clean(node.output())


def test_damaged_bag_is_one_error_line_naming_the_file(tmp_path: Path, probe: Probe) -> None:
    bag = rosbags_bag(tmp_path / "bag", "/t5")
    (mcap,) = sorted(bag.glob("*.mcap"))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) * 2 // 3])  # cut short, like a recorder that crashed
    node = replay(tmp_path, bag, "rate:=0.0", "wait_for_subscribers:=false")
    rc = node.wait(60)
    text = node.output()
    assert rc == 1, text
    errors = [line for line in text.splitlines() if "ERROR" in line]
    assert len(errors) == 1 and mcap.name in errors[0], text
    assert_clean(text)


@pytest.mark.parametrize(("params", "name"), [
    ((), "bag"),
    (("bag:=/nonexistent/bag", "rate:=-1.0"), "rate"),
    (("bag:=/nonexistent/bag", "remap:=['nonsense']"), "remap"),
])
def test_bad_parameters_are_refused_naming_them(tmp_path: Path, params: tuple[str, ...],
                                                name: str) -> None:
    args: list[str] = []
    for p in params:
        args += ["-p", p]
    node = NodeProcess("replay", args, tmp_path)
    rc = node.wait(30)
    assert rc == 2, node.output()
    assert f"parameter '{name}'" in node.output()
    assert_clean(node.output())
