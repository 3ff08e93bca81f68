"""Readiness from the live solve, over real DDS: the sample bag replayed into the node.

The node's diagnostics carry the projection uncertainty of its live solve ("not yet"
before one); ``ready`` turns true once min_views are collected and the uncertainty is at
or below ``readiness.max_uncertainty``; the camera solved then is as good as that promises
against the bag's true camera; and ``~/calibrate``'s answer says how far from ready it is.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import CameraInfo
from std_srvs.srv import Trigger

from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.camera_info import read_camera_info_yaml
from test.integration.frames import CalibrationBag
from test.integration.qos import LATCHED, RELIABLE
from test.integration.ros_harness import (
    NodeProcess,
    Probe,
    calibrator_node,
    diagnostics_values,
    wait_until,
)

pytestmark = pytest.mark.integration

MAX_UNCERTAINTY_PX = 0.1  # readiness.max_uncertainty's default (config/calibrator.yaml)


def uncertainty_px(values: dict[str, str]) -> float | None:
    """The live solve's RMS projection uncertainty from the diagnostics (None: not yet)."""
    text = values.get("projection uncertainty", "")
    return None if not text or text.startswith("not yet") else float(text.split()[0])


def test_ready_turns_true_when_the_uncertainty_is_low_enough(
        tmp_path: Path, probe: Probe, bag: CalibrationBag) -> None:
    node = calibrator_node(tmp_path, "cal_ready", image_topic="/ready/image")
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    wait_until(lambda: diagnostics_values(diagnostics, "cal_ready"), 60, "the first diagnostics")
    first = diagnostics_values(diagnostics, "cal_ready")
    assert first["projection uncertainty"] == "not yet (0 views)", first
    assert first["ready"] == "false"
    assert first["projection uncertainty needed"] == f"{MAX_UNCERTAINTY_PX:.3f}"
    assert first["next pose"] == "after the first view"
    replay = NodeProcess("replay", ["-p", f"bag:={bag.path}", "-p", "rate:=1.0",
                                    "-p", "loop:=true", "-r", f"{bag.topic}:=/ready/image"],
                         tmp_path)
    try:
        ready = wait_until(
            lambda: (v := diagnostics_values(diagnostics, "cal_ready")).get("ready") == "true"
            and v, 240, "ready to turn true")
    finally:
        replay.stop()
    # Every report before it said what was missing, in words, and the uncertainty once known.
    reports = [diagnostics_values([a], "cal_ready") for a in diagnostics]
    reports = [r for r in reports if r]
    before = reports[:next(k for k, r in enumerate(reports) if r["ready"] == "true")]
    assert all(r["missing"] for r in before)
    known = [r for r in before if uncertainty_px(r) is not None]
    for r in known:
        if int(r["views"]) >= int(r["views needed"]):
            assert uncertainty_px(r) > MAX_UNCERTAINTY_PX or "solving" in r["missing"], r
            assert "projection uncertainty" in r["missing"], r
    u = uncertainty_px(ready)
    assert u is not None and 0 < u <= MAX_UNCERTAINTY_PX, ready
    assert int(ready["views"]) >= int(ready["views needed"]) and ready["missing"] == ""
    # Where to hold the board next, in words, from the live solve's estimate.
    assert any(w in ready["next pose"] for w in ("corner", "edge", "centre")), ready["next pose"]

    answer = probe.call(Trigger, "/cal_ready/calibrate", timeout=120)
    assert answer.success, answer.message
    assert "ready: projection uncertainty" in answer.message, answer.message
    infos = probe.collect(CameraInfo, "/camera_info", LATCHED)
    wait_until(lambda: infos, 20, "the latched CameraInfo")
    # Ready means good: the solve is within twice the bound of the true camera.
    solved = read_camera_info_yaml(tmp_path / "cal_ready.yaml")
    true_rms, _ = projection_difference(bag.camera, solved)
    assert true_rms <= 2 * MAX_UNCERTAINTY_PX, (true_rms, answer.message)
    rc = node.stop()
    assert rc in (0, -2, 130), node.output()[-3000:]


def test_calibrate_says_how_far_from_ready(tmp_path: Path, probe: Probe,
                                           bag: CalibrationBag) -> None:
    # A bound no calibration meets: the answer solves and says how far it is.
    node = calibrator_node(tmp_path, "cal_far", "readiness.max_uncertainty:=0.0001",
                           "min_views:=4", image_topic="/far/image")
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    replay = NodeProcess("replay", ["-p", f"bag:={bag.path}", "-p", "rate:=1.0",
                                    "-p", "loop:=true", "-r", f"{bag.topic}:=/far/image"],
                         tmp_path)
    try:
        values = wait_until(
            lambda: (v := diagnostics_values(diagnostics, "cal_far")) and uncertainty_px(v)
            and int(v["views"]) >= 4 and v, 240, "a live solve of 4 views")
    finally:
        replay.stop()
    assert values["ready"] == "false"
    assert "projection uncertainty" in values["missing"] and "needs <= 0.0001 px" in \
        values["missing"], values["missing"]
    answer = probe.call(Trigger, "/cal_far/calibrate", timeout=120)
    assert answer.success, answer.message
    assert "not ready yet: projection uncertainty" in answer.message, answer.message
    assert "x the bound" in answer.message
    rc = node.stop()
    assert rc in (0, -2, 130), node.output()[-3000:]


def test_a_bad_bound_refuses_start_up_naming_it(tmp_path: Path) -> None:
    node = calibrator_node(tmp_path, "cal_bad_bound", "readiness.max_uncertainty:=-0.5")
    assert node.wait(60) == 2
    assert "readiness.max_uncertainty" in node.output()
