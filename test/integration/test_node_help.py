"""The node executables' command line, as a user types it: ``calibrator --help`` (and
``replay --help``, ``calibrator --ros-args --help``) print the parameters and exit 0 without
starting ROS (rcl would create its log directory); a stray, unknown or malformed ROS argument
is one line and exit status 2, never a traceback."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

import pytest

from test.integration.ros_harness import BIN

pytestmark = pytest.mark.integration


def run(tmp_path: Path, *argv: str) -> subprocess.CompletedProcess[str]:
    log_dir = tmp_path / "ros_log"
    env = {**os.environ, "ROS_LOG_DIR": str(log_dir)}
    try:
        return subprocess.run([str(BIN / argv[0]), *argv[1:]], env=env, capture_output=True,
                              text=True, timeout=120, stdin=subprocess.DEVNULL, check=False)
    except subprocess.TimeoutExpired as e:  # a node that started instead
        raise AssertionError(f"{' '.join(argv)} still running after 120 s: {e.stderr!r}"
                             ) from None


@pytest.mark.parametrize("argv", [
    ("calibrator", "--help"), ("calibrator", "-h"), ("calibrator", "--ros-args", "--help"),
    ("calibrator", "--ros-args", "-p", "min_views:=3", "--help"),
])
def test_calibrator_help_lists_parameters_without_starting_ros(
        tmp_path: Path, argv: tuple[str, ...]) -> None:
    done = run(tmp_path, *argv)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: calibrator"), done.stdout[:300]
    assert "  board.type (default marker_grid)" in done.stdout
    assert "  resume (default false)" in done.stdout and "--params-file FILE" in done.stdout
    assert "Traceback" not in done.stderr and "calibrating from" not in done.stderr
    assert not (tmp_path / "ros_log").exists(), "rclpy was started"


def test_replay_help_lists_its_parameters(tmp_path: Path) -> None:
    done = run(tmp_path, "replay", "--help")
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: replay")
    assert "  bag (default '')" in done.stdout and "  rate (default 1.0)" in done.stdout
    assert not (tmp_path / "ros_log").exists(), "rclpy was started"


@pytest.mark.parametrize(("argv", "words"), [
    (("calibrator", "--foo"), "unknown argument '--foo'"),
    (("replay", "--foo"), "unknown argument '--foo'"),
    (("calibrator", "--ros-args", "--no-such-flag"), "unknown ROS argument(s) '--no-such-flag'"),
    (("calibrator", "--ros-args", "-p"), "Couldn't parse trailing -p flag"),
])
def test_a_bad_argument_is_one_line_and_status_2(tmp_path: Path, argv: tuple[str, ...],
                                                  words: str) -> None:
    done = run(tmp_path, *argv)
    assert done.returncode == 2, (done.stdout, done.stderr)
    assert "Traceback" not in done.stderr, done.stderr
    # rcl logs an [ERROR] line of its own before a ROS argument it cannot parse
    lines = [line for line in done.stderr.splitlines() if line.startswith(f"{argv[0]}: ")]
    assert len(lines) == 1 and words in lines[0] and "--help" in lines[0], done.stderr
