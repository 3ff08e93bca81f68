"""Stop signals reach the real nodes at their busiest: they exit 0, quietly.

Ctrl-C in a terminal, a second one forwarded by ``ros2 launch`` 50 ms later, a user
hammering Ctrl-C, a SIGTERM from a supervisor (alone, or after a SIGINT that seemed to do
nothing): whatever the mix, the calibrator (while detection runs on a stream of frames, and
while a solve runs) and the replay node (while playing, and while waiting for a subscriber)
must end with status 0 and write no traceback, no KeyboardInterrupt, no RCLError from a
publisher whose context is gone and no "Failed to publish log message to rosout".
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from test.integration.frames import CalibrationBag, image_messages
from test.integration.qos import RELIABLE
from test.integration.ros_harness import (
    NodeProcess,
    Probe,
    calibrator_node,
    diagnostics_values,
    wait_until,
)
from test.integration.streaming import Streamer

pytestmark = pytest.mark.integration

# What a clean stop must never print.
BAD_OUTPUT = ("Traceback", "KeyboardInterrupt", "RCLError", "Failed to publish",
              "context is invalid", "[ERROR]")
INT, TERM = signal.SIGINT, signal.SIGTERM
# (seconds after the previous signal, signal)
PATTERNS: dict[str, list[tuple[float, int]]] = {
    "sigint": [(0.0, INT)],
    "sigint-twice-50ms": [(0.0, INT), (0.05, INT)],
    "sigint-5-times": [(0.0, INT), (0.02, INT), (0.05, INT), (0.1, INT), (0.2, INT)],
    "sigterm": [(0.0, TERM)],
    "sigint-then-sigterm": [(0.0, INT), (0.05, TERM)],
}
EXIT_BOUND_S = 20.0  # the node must be gone by then (it takes ~1-3 s here)


@pytest.fixture(scope="module")
def frames(bag: CalibrationBag) -> list[Image]:
    msgs = image_messages(bag)
    return [msgs[i] for i in np.linspace(0, len(msgs) - 1, 10).round().astype(int)]


def send_signals(node: NodeProcess, pattern: Sequence[tuple[float, int]]) -> None:
    for delay, sig in pattern:
        time.sleep(delay)
        if node.running():
            os.killpg(node.proc.pid, sig)


def assert_quiet_exit(node: NodeProcess) -> None:
    status = node.wait(EXIT_BOUND_S)
    text = node.output()
    assert status == 0, f"exit {status}\n{text[-4000:]}"
    for bad in BAD_OUTPUT:
        assert bad not in text, f"{bad!r} in the output:\n{text[-4000:]}"


def diag(diagnostics: list[Any], name: str, key: str) -> int:
    return int(diagnostics_values(diagnostics, name).get(key, 0))


@pytest.mark.parametrize("pattern", list(PATTERNS))
def test_calibrator_stops_quietly_while_receiving_images(
        tmp_path: Path, probe: Probe, frames: list[Image], pattern: str) -> None:
    name = f"cal_sig_img_{pattern.replace('-', '_')}"
    topic = f"/{name}/in"
    node = calibrator_node(tmp_path, name, image_topic=topic)
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    overlay = probe.collect(Image, f"/{name}/overlay", RELIABLE)  # so overlays are made
    publisher = probe.node.create_publisher(Image, topic, RELIABLE)
    # Faster than detection: the worker is inside a frame when the signal comes.
    streamer = Streamer(publisher, frames, 0.1)
    try:
        wait_until(lambda: overlay and diag(diagnostics, name, "frames processed") >= 2, 90,
                   "the node to process frames")
        send_signals(node, PATTERNS[pattern])
        assert_quiet_exit(node)
    finally:
        streamer.stop()
        probe.node.destroy_publisher(publisher)


@pytest.mark.parametrize("pattern", ["sigint-twice-50ms", "sigint-5-times", "sigterm",
                                     "sigint-then-sigterm"])
def test_calibrator_stops_quietly_while_solving(
        tmp_path: Path, probe: Probe, frames: list[Image], pattern: str) -> None:
    name = f"cal_sig_solve_{pattern.replace('-', '_')}"
    topic = f"/{name}/in"
    node = calibrator_node(tmp_path, name, "min_views:=4", image_topic=topic)
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    publisher = probe.node.create_publisher(Image, topic, RELIABLE)
    streamer = Streamer(publisher, frames, 0.1)
    client = probe.node.create_client(Trigger, f"/{name}/calibrate")
    try:
        wait_until(lambda: diag(diagnostics, name, "views") >= 6, 180, "6 views")
        assert client.wait_for_service(timeout_sec=30)
        client.call_async(Trigger.Request())
        wait_until(lambda: "solving from" in node.output(), 30, "the solve to start")
        send_signals(node, PATTERNS[pattern])
        assert_quiet_exit(node)
    finally:
        streamer.stop()
        probe.node.destroy_client(client)
        probe.node.destroy_publisher(publisher)


@pytest.mark.parametrize("pattern", list(PATTERNS))
def test_replay_stops_quietly_while_playing(tmp_path: Path, probe: Probe, bag: CalibrationBag,
                                            pattern: str) -> None:
    topic = f"/replay_sig_{pattern.replace('-', '_')}/image"
    received = probe.collect(Image, topic, RELIABLE)
    node = NodeProcess("replay", ["-p", f"bag:={bag.path}", "-p", "rate:=4.0", "-p",
                                  "loop:=true", "-r", f"{bag.topic}:={topic}"], tmp_path,
                       name=f"replay_{pattern}")
    wait_until(lambda: len(received) >= 2, 60, "the replay to play")
    send_signals(node, PATTERNS[pattern])
    assert_quiet_exit(node)


@pytest.mark.parametrize("pattern", ["sigint-twice-50ms", "sigterm"])
def test_replay_stops_quietly_while_waiting_for_a_subscriber(
        tmp_path: Path, bag: CalibrationBag, pattern: str) -> None:
    node = NodeProcess("replay", ["-p", f"bag:={bag.path}", "-r",
                                  f"{bag.topic}:=/replay_nobody/image"], tmp_path,
                       name=f"replay_wait_{pattern}")
    wait_until(lambda: "playing" in node.output(), 60, "the replay to start")
    send_signals(node, PATTERNS[pattern])
    assert_quiet_exit(node)
