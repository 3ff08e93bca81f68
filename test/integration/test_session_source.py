"""The real node and a saved session of another source.

A session saved from another image topic (the demo's, say) is not resumed: with
``resume:=true`` the node refuses to start with one line saying whose session it is and what
to do, and exits 2, leaving the file as it was. A session saved before the source was
recorded still resumes, and the log says so. Sessions live under ``$ROS_HOME/artcal/``.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.live.saved_session import (
    FILE_NAME,
    SessionSource,
    load_session,
    write_session,
)
from test.integration.ros_harness import NodeProcess, calibrator_node, wait_until
from test.unit.test_saved_session import views

pytestmark = pytest.mark.integration

CAMERA = "sourcecam"
BOARD = Board()  # config/calibrator.yaml's board


def start(tmp_path: Path, name: str) -> NodeProcess:
    env = {**os.environ, "HOME": str(tmp_path / "home"), "ROS_HOME": str(tmp_path / "ros")}
    return calibrator_node(tmp_path, name, f"camera_name:={CAMERA}", "resume:=true", env=env)


def session_path(tmp_path: Path) -> Path:
    return tmp_path / "ros" / "artcal" / CAMERA / FILE_NAME


def test_a_session_of_another_image_topic_is_refused_at_start(tmp_path: Path) -> None:
    path = session_path(tmp_path)
    write_session(path, views(4), BOARD, SessionSource(CAMERA, "/demo/image", BOARD.describe()))
    node = start(tmp_path, "cal_src")  # reads /cal_src/image
    assert node.wait(90) == 2
    text = node.output()
    assert "Traceback" not in text, text
    refusal = [line for line in text.splitlines() if "refusing to start" in line]
    assert len(refusal) == 1, text
    line = refusal[0]
    assert "[FATAL]" in line and f"{path.parent}/" in line, line
    assert "recorded from /demo/image" in line and "this node reads /cal_src/image" in line
    assert "start without resume:=true" in line and "camera_name" in line, line
    assert load_session(path).source == SessionSource(CAMERA, "/demo/image", BOARD.describe())


def test_a_session_saved_without_its_source_still_resumes(tmp_path: Path) -> None:
    path = session_path(tmp_path)
    write_session(path, views(4), BOARD)  # as the versions before the source was saved
    node = start(tmp_path, "cal_old")
    wait_until(lambda: "does not say which image topic" in node.output(), 90,
               "the log line about a session without its source")
    assert "resumed 4 views" in node.output()
    assert node.stop() == 0
