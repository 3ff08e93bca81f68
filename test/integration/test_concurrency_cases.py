"""Each concurrent case of the calibrator's services, one at a time, with its defined answer.

On one real node: ``~/calibrate`` with zero views (refused, saying how many are needed);
``~/calibrate`` twice at once (one solves, the other is told one is running, or solves after
it); ``~/reset`` during a solve (answered at once; the solve finishes on the views it
started with, and the collection is empty afterwards); a parameter change during a solve
(accepted at once; the next solve uses it). No call waits past its bound, nothing deadlocks,
and the node exits 0 on SIGINT without a traceback. SIGINT in the middle of a solve is in
test_shutdown.py::test_calibrator_stops_quietly_while_solving.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from test.integration.frames import CalibrationBag, image_messages
from test.integration.qos import RELIABLE
from test.integration.ros_harness import (
    Probe,
    calibrator_node,
    diagnostics_values,
    wait_until,
)
from test.integration.streaming import Streamer

pytestmark = pytest.mark.integration

NAME = "cal_cases"
MIN_VIEWS = 4
VIEWS = 8  # collected before each solve case: a solve of a few seconds here
QUICK_S = 10.0  # a reset or a parameter change never waits for the solve
SOLVE_S = 120.0


def answer_within(future: Any, bound: float, what: str) -> Any:
    wait_until(future.done, bound, f"{what} to be answered")
    return future.result()


def test_each_concurrent_case_has_its_defined_answer(tmp_path: Path, probe: Probe,
                                                     bag: CalibrationBag) -> None:
    node = calibrator_node(tmp_path, NAME, f"min_views:={MIN_VIEWS}")
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    frames = image_messages(bag)
    frames = [frames[i] for i in np.linspace(0, len(frames) - 1, 12).round().astype(int)]
    publisher = probe.node.create_publisher(Image, f"/{NAME}/image", RELIABLE)
    calibrate = [probe.node.create_client(Trigger, f"/{NAME}/calibrate") for _ in range(2)]
    reset = probe.node.create_client(Trigger, f"/{NAME}/reset")
    set_params = probe.node.create_client(SetParameters, f"/{NAME}/set_parameters")

    def views() -> int:
        return int(diagnostics_values(diagnostics, NAME).get("views", -1))

    def collect(n: int) -> None:
        streamer = Streamer(publisher, frames, 0.2)
        try:
            wait_until(lambda: views() >= n, 180, f"{n} views")
        finally:
            streamer.stop()

    def solving_started(before: int) -> None:
        wait_until(lambda: node.output().count("solving from") > before, 30,
                   "the solve to start")

    try:
        for client in [*calibrate, reset, set_params]:
            assert client.wait_for_service(timeout_sec=30)

        # Zero views: refused, with what is needed.
        empty = answer_within(calibrate[0].call_async(Trigger.Request()), QUICK_S,
                              "~/calibrate with zero views")
        assert not empty.success
        assert "not enough views" in empty.message and f"views 0/{MIN_VIEWS}" in empty.message

        # Twice at once: one solve; the other is refused as busy, or solves after it.
        collect(VIEWS)
        futures = [c.call_async(Trigger.Request()) for c in calibrate]
        both = [answer_within(f, SOLVE_S, "each of two ~/calibrate at once") for f in futures]
        assert any(a.success for a in both), [a.message for a in both]
        for a in both:
            assert a.success or "already running" in a.message, a.message

        # A reset during a solve: answered at once; the solve ends on its own views.
        before = node.output().count("solving from")
        solve = calibrate[0].call_async(Trigger.Request())
        solving_started(before)
        t0 = time.monotonic()
        cleared = answer_within(reset.call_async(Trigger.Request()), QUICK_S, "~/reset")
        assert cleared.success and "cleared" in cleared.message, cleared.message
        reset_s = time.monotonic() - t0
        solved = answer_within(solve, SOLVE_S, "the solve during the reset")
        assert solved.success, solved.message
        reports = len(diagnostics)
        wait_until(lambda: int(diagnostics_values(diagnostics[reports:], NAME).get(
            "views", -1)) == 0, 20, "an empty collection after the reset")

        # A parameter change during a solve: accepted at once; the next solve uses it.
        collect(VIEWS)
        before = node.output().count("solving from")
        solve = calibrate[0].call_async(Trigger.Request())
        solving_started(before)
        change = SetParameters.Request(parameters=[ParameterMsg(
            name="calibrate.fix_aspect_ratio",
            value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=True))])
        result = answer_within(set_params.call_async(change), QUICK_S,
                               "a parameter change during a solve")
        assert result.results[0].successful, result.results[0].reason
        assert answer_within(solve, SOLVE_S, "the solve during the change").success
        after = answer_within(calibrate[1].call_async(Trigger.Request()), SOLVE_S,
                              "the solve after the change")
        assert after.success and "fx = fy" in after.message, after.message
        print(f"reset answered {reset_s:.2f} s into a solve")
    finally:
        for client in [*calibrate, reset]:
            probe.node.destroy_client(client)
        probe.node.destroy_client(set_params)
        probe.node.destroy_publisher(publisher)
    status = node.stop()
    log = node.output()
    assert status == 0, log[-3000:]
    for bad in ("Traceback", "[ERROR]", "KeyboardInterrupt"):
        assert bad not in log, log[-3000:]
