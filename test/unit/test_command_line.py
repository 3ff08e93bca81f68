"""The nodes' command line without ROS: ``--help`` lists every parameter with its default,
before or inside ``--ros-args``; a stray argument is one line and status 2; ROS arguments are
told apart from the node's own as rcl does (``--ros-args ... --`` blocks)."""

from __future__ import annotations

import io

import pytest

from artcal_ros.core.params import PARAMETERS
from artcal_ros.ros import calibrator, replay
from artcal_ros.ros.command_line import handle_arguments, split_arguments


def run(argv: list[str], command: object = calibrator.HELP) -> tuple[int | None, str, str]:
    out, err = io.StringIO(), io.StringIO()
    status = handle_arguments(argv, command, out=out, err=err)  # type: ignore[arg-type]
    return status, out.getvalue(), err.getvalue()


def test_ros_blocks_are_split_from_the_nodes_own_arguments() -> None:
    assert split_arguments(["--ros-args", "-p", "a:=1", "-r", "image:=/x"]) == (
        [], ["-p", "a:=1", "-r", "image:=/x"])
    assert split_arguments(["mine", "--ros-args", "-p", "a:=1", "--", "also", "--ros-args",
                            "--log-level", "debug"]) == (
        ["mine", "also"], ["-p", "a:=1", "--log-level", "debug"])


@pytest.mark.parametrize("argv", [
    ["calibrator", "--help"], ["calibrator", "-h"], ["calibrator", "--ros-args", "--help"],
    ["calibrator", "--ros-args", "-p", "min_views:=3", "-h"],
])
def test_help_lists_every_calibrator_parameter_with_its_default(argv: list[str]) -> None:
    status, out, err = run(argv)
    assert status == 0 and err == ""
    assert out.startswith("usage: calibrator")
    for spec in PARAMETERS:
        assert f"  {spec.name} (default " in out, spec.name
    assert "  board.type (default marker_grid)" in out
    assert "  resume (default false)" in out
    assert "  min_views (default 10)" in out
    assert "--params-file FILE" in out and "-r, --remap FROM:=TO" in out
    assert max(len(line) for line in out.splitlines()) <= 99


def test_replay_help_lists_its_own_parameters() -> None:
    status, out, _ = run(["replay", "--help"], replay.HELP)
    assert status == 0 and out.startswith("usage: replay")
    for line in ("  bag (default '')", "  rate (default 1.0)", "  loop (default false)",
                 "  qos (default recorded)", "  topics (default [])", "  remap (default [])"):
        assert line in out, line
    assert "board.type" not in out


def test_an_unknown_argument_is_one_line_and_status_2() -> None:
    status, out, err = run(["calibrator", "--foo"])
    assert status == 2 and out == ""
    assert err.count("\n") == 1
    assert "unknown argument '--foo'" in err and "--ros-args -p NAME:=VALUE" in err
    assert "calibrator --help" in err


def test_ros_arguments_alone_start_the_node() -> None:
    assert run(["calibrator"]) == (None, "", "")
    assert run(["calibrator", "--ros-args", "-p", "min_views:=3", "--params-file", "x.yaml",
                "-r", "__node:=cal"]) == (None, "", "")
