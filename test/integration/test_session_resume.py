"""The saved session over a real ``kill -9`` of the real node.

Views stream in until the session file under ``$HOME/.ros/artcal/<camera_name>/`` holds
some; the node is SIGKILLed (no chance to save anything more); started again with
``resume:=true`` it reports those views at once and calibrates from them without a new
frame. Started with the default ``resume:=false`` it starts empty and says how to resume;
a damaged session file is refused with a warning and the node starts empty.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from artcal_ros.core.board import Board
from artcal_ros.core.live.saved_session import FILE_NAME, SessionFileError, read_session
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

CAMERA = "resumecam"
# Every start reads the same camera: a session of another image topic is not resumed.
IMAGE_TOPIC = f"/{CAMERA}/image"
SAVED_VIEWS = 5  # wait for this many in the file before the kill
MIN_VIEWS = 4


def start(tmp_path: Path, name: str, *params: str) -> NodeProcess:
    return calibrator_node(tmp_path, name, f"camera_name:={CAMERA}", f"min_views:={MIN_VIEWS}",
                           *params, image_topic=IMAGE_TOPIC,
                           env={**os.environ, "HOME": str(tmp_path / "home")})


def saved_views(path: Path) -> int:
    try:
        return len(read_session(path, Board()).views)
    except SessionFileError:
        return 0


def views_now(diagnostics: list[object], name: str) -> int:
    return int(diagnostics_values(diagnostics, name).get("views", -1))


def test_views_survive_kill_9_and_resume(tmp_path: Path, probe: Probe,
                                         bag: CalibrationBag) -> None:
    session = tmp_path / "home" / ".ros" / "artcal" / CAMERA / FILE_NAME
    frames = image_messages(bag)
    frames = [frames[i] for i in np.linspace(0, len(frames) - 1, 12).round().astype(int)]
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)

    node = start(tmp_path, "cal_kill")
    publisher = probe.node.create_publisher(Image, IMAGE_TOPIC, RELIABLE)
    streamer = Streamer(publisher, frames, 0.3)
    try:
        n = wait_until(lambda: (lambda k: k if k >= SAVED_VIEWS else 0)(saved_views(session)),
                       180, f"{SAVED_VIEWS} views in {session}")
        os.killpg(node.proc.pid, signal.SIGKILL)
        assert node.proc.wait(10) == -signal.SIGKILL
    finally:
        streamer.stop()
        probe.node.destroy_publisher(publisher)
    n = max(n, saved_views(session))  # a save may have finished just before the kill

    resumed = start(tmp_path, "cal_resumed", "resume:=true")
    wait_until(lambda: views_now(diagnostics, "cal_resumed") >= n, 60,
               f"{n} resumed views in the diagnostics")
    assert f"resumed {n} views" in resumed.output()
    answer = probe.call(Trigger, "/cal_resumed/calibrate", timeout=120)
    assert answer.success, answer.message
    assert resumed.stop() == 0
    assert saved_views(session) == n, "a clean stop keeps the session"

    fresh = start(tmp_path, "cal_fresh")
    wait_until(lambda: views_now(diagnostics, "cal_fresh") == 0, 60, "an empty collection")
    text = fresh.output()
    assert f"earlier session of {n} views" in text and "resume:=true" in text, text
    assert fresh.stop() == 0
    assert saved_views(session) == n, "an unresumed session is left as it was"

    session.write_bytes(b"\x00garbage" * 50)
    refused = start(tmp_path, "cal_refused", "resume:=true")
    wait_until(lambda: views_now(diagnostics, "cal_refused") == 0, 60, "an empty collection")
    text = refused.output()
    assert "[WARN]" in text and "session not resumed, starting empty" in text, text
    assert str(session) in text and "Traceback" not in text
    assert refused.stop() == 0
