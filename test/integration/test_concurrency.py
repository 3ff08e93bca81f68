"""The calibrator node under concurrent load, over real DDS, started as the real console script.

Frames stream in (faster than detection, so the keep-latest worker drops some) while several
threads, on three client nodes, call ``~/calibrate`` and ``~/reset`` over and over. Every call
must be answered within a bound (success, or failure with a reason), the node must log no
traceback or error, keep processing frames afterwards, calibrate after a final reset once it
has enough views again, and exit 0 on SIGINT.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
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
    PARAMS,
    NodeProcess,
    Probe,
    diagnostics_values,
    wait_until,
)
from test.integration.streaming import Streamer

pytestmark = pytest.mark.integration

NAME = "cal_conc"
TOPIC = "/conc/image"
MIN_VIEWS = 3  # low, so that solves (and "already running") happen during the storm
STREAM_FRAMES = 12  # distinct views, cycled
STREAM_PERIOD_S = 0.15  # faster than detection (~0.5 s a frame): frames are dropped too
CALLERS = 4  # threads calling the services, spread over three client nodes
RESET_SHARE = 0.05  # of the calls; rare enough that views pile up to MIN_VIEWS in between
STORM_CALLS = 40  # the storm lasts at least this many calls, ...
STORM_SOLVES = 3  # ... this many of them solves ...
STORM_RESETS = 2  # ... and this many resets (bounded by STORM_MAX_S)
STORM_MAX_S = 240.0
# Bounds for an answer on a busy 2-core machine: a reset never waits for anything; a
# calibrate may wait for a solve of up to STREAM_FRAMES views (seconds, here).
RESET_BOUND_S = 30.0
CALIBRATE_BOUND_S = 120.0


@dataclass
class Answer:
    """One service call and what came back (``success`` None: no answer within the bound)."""

    service: str
    success: bool | None
    message: str
    seconds: float


@pytest.fixture
def callers() -> Iterator[list[Probe]]:
    """Two more client nodes (own contexts and DDS participants) besides the session probe."""
    extra = [Probe(f"artcal_conc_client_{k}") for k in range(2)]
    yield extra
    for p in extra:
        p.close()


def call(client: Any, bound: float) -> tuple[bool | None, str, float]:
    """One Trigger call; (success or None if unanswered within ``bound`` s, message, s)."""
    t0 = time.monotonic()
    future = client.call_async(Trigger.Request())
    deadline = t0 + bound
    while not future.done():
        if time.monotonic() > deadline:
            client.remove_pending_request(future)
            return None, "", time.monotonic() - t0
        time.sleep(0.02)
    answer = future.result()
    return bool(answer.success), str(answer.message), time.monotonic() - t0


def counter(diagnostics: list[Any], key: str, since: int = 0) -> int:
    """A diagnostics value of the node, from reports after the first ``since`` (-1: none)."""
    values = diagnostics_values(diagnostics[since:], NAME)
    return int(values[key]) if key in values else -1


def test_concurrent_service_calls_while_streaming(tmp_path: Path, probe: Probe,
                                                  callers: list[Probe],
                                                  bag: CalibrationBag) -> None:
    node = NodeProcess("calibrator", [
        "--params-file", str(PARAMS), "-r", f"__node:={NAME}", "-r", f"image:={TOPIC}",
        "-p", f"output_file:={tmp_path / (NAME + '.yaml')}", "-p", f"min_views:={MIN_VIEWS}",
    ], tmp_path, name=NAME)
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    frames = image_messages(bag)
    frames = [frames[i] for i in np.linspace(0, len(frames) - 1, STREAM_FRAMES).round()
              .astype(int)]
    publisher = probe.node.create_publisher(Image, TOPIC, RELIABLE)
    nodes = [probe, *callers]
    clients = {(p.node.get_name(), srv): p.node.create_client(Trigger, f"/{NAME}/{srv}")
               for p in nodes for srv in ("calibrate", "reset")}
    streamer = Streamer(publisher, frames, STREAM_PERIOD_S)
    answers: list[Answer] = []
    errors: list[BaseException] = []
    try:
        # The stream is repeated, so the first frames lost to discovery do not matter.
        wait_until(lambda: counter(diagnostics, "frames processed") > 0, 90,
                   "the node to process a first frame")
        for (owner, srv), client in clients.items():
            assert client.wait_for_service(timeout_sec=30.0), f"{owner} sees no ~/{srv}"

        storm_over = threading.Event()

        def caller(k: int) -> None:
            owner = nodes[k % len(nodes)].node.get_name()
            rng = random.Random(k)
            try:
                while not storm_over.is_set():
                    srv = "reset" if rng.random() < RESET_SHARE else "calibrate"
                    bound = CALIBRATE_BOUND_S if srv == "calibrate" else RESET_BOUND_S
                    success, message, took = call(clients[(owner, srv)], bound)
                    answers.append(Answer(srv, success, message, took))
                    if success is None:
                        storm_over.set()  # a failure already; the assertion below says so
                    time.sleep(rng.uniform(0.3, 1.0))
            except BaseException as e:  # reported below, with the node's log
                errors.append(e)
                storm_over.set()

        def solves() -> int:  # the calibrate calls that ran a solve (not refused before one)
            return sum(1 for a in list(answers) if a.service == "calibrate" and (
                a.success or a.message.startswith("calibration failed")))

        def resets() -> int:
            return sum(1 for a in list(answers) if a.service == "reset")

        threads = [threading.Thread(target=caller, args=(k,), name=f"caller{k}")
                   for k in range(CALLERS)]
        for t in threads:
            t.start()
        try:
            wait_until(lambda: storm_over.is_set() or (
                len(answers) >= STORM_CALLS and solves() >= STORM_SOLVES
                and resets() >= STORM_RESETS), STORM_MAX_S,
                f"{STORM_CALLS} calls, {STORM_SOLVES} solves and {STORM_RESETS} resets among "
                "them")
        finally:
            storm_over.set()
            for t in threads:
                # Every call has its own bound; this only catches a caller stuck elsewhere.
                t.join(CALIBRATE_BOUND_S + 5.0)
        log = node.output()
        assert not any(t.is_alive() for t in threads), f"a caller hung\n{log[-3000:]}"
        assert not errors, f"{errors[0]!r}\n{log[-3000:]}"
        unanswered = [a for a in answers if a.success is None]
        assert not unanswered, f"{len(unanswered)} calls unanswered within the bound: " \
            f"{unanswered[:3]}\n{log[-3000:]}"
        for a in answers:
            assert a.message, f"~/{a.service} answered {a.success} without a reason"
        assert solves() >= STORM_SOLVES and resets() >= STORM_RESETS, \
            f"{len(answers)} calls, {solves()} solves, {resets()} resets"

        # Still processing frames after the storm (the stream goes on).
        before = counter(diagnostics, "frames processed")
        wait_until(lambda: counter(diagnostics, "frames processed") > before, 60,
                   "frames processed to grow after the service calls")

        # A final reset, enough views again (in reports made after the reset), a solve.
        cleared = probe.call(Trigger, f"/{NAME}/reset", timeout=RESET_BOUND_S)
        assert cleared.success and "cleared" in cleared.message, cleared.message
        reports = len(diagnostics)
        wait_until(lambda: counter(diagnostics, "views", reports) >= MIN_VIEWS + 2, 180,
                   f"{MIN_VIEWS + 2} views after the final reset")
        solved = probe.call(Trigger, f"/{NAME}/calibrate", timeout=CALIBRATE_BOUND_S)
        assert solved.success, solved.message
        assert "RMS" in solved.message
    finally:
        streamer.stop()
        probe.node.destroy_publisher(publisher)
        for (owner, _), client in clients.items():
            next(p for p in nodes if p.node.get_name() == owner).node.destroy_client(client)
    status = node.stop()
    log = node.output()
    assert status == 0, f"exit {status} on SIGINT\n{log[-3000:]}"
    for bad in ("Traceback", "[ERROR]", "[FATAL]"):
        assert bad not in log, f"{bad} in the node's log:\n{log[-5000:]}"
    busy = sum(1 for a in answers if "already running" in a.message)
    print(f"{len(answers)} calls answered ({solves()} solves, {resets()} resets, {busy} "
          f"'already running'), slowest {max(a.seconds for a in answers):.1f} s; "
          f"{streamer.sent} frames sent")
