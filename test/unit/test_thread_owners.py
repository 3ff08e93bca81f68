"""Every thread the live stream and the solve start belongs to one object, which joins it:
after the owner's close (stop) no thread it started is still running, a solve comes back
as a Future, and a solve in progress ends at its next stage when its worker closes."""

from __future__ import annotations

import threading
from concurrent.futures import Future
from pathlib import Path

import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.solve_run import (
    CancelledError,
    SolveRun,
    SolveWorker,
    queue_report,
)
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import CalibrationError
from artcal_ros.core.live.coverage import CoverageConfig, ViewCollector
from artcal_ros.core.live.saved_session import SessionStore
from artcal_ros.core.live.stream import LiveDetection
from artcal_ros.core.params import load_params
from artcal_ros.ros.latest import LatestWorker
from artcal_ros.synth import Camera
from test.unit.noisy_views import noisy_views

ROOT = Path(__file__).resolve().parents[2]
PARAMS = ROOT / "config" / "calibrator.yaml"
BOARD = Board()
CAM = Camera.preset("webcam")


def views(n: int, seed: int) -> list[Detections]:
    return noisy_views(CAM, n, seed)


def started_since(before: set[threading.Thread]) -> dict[str, threading.Thread]:
    return {t.name: t for t in threading.enumerate() if t not in before}


def test_no_thread_outlives_its_owners_close(tmp_path: Path) -> None:
    before = set(threading.enumerate())
    collector = ViewCollector(BOARD, CoverageConfig(min_views=3))
    live = LiveDetection(BOARD, lambda image: Detections.empty(image.shape[1::-1]), collector)
    track: LatestWorker[int] = LatestWorker(lambda _item: None, lambda _e: None, name="track")
    solver = SolveWorker()
    store = SessionStore(tmp_path / "session.npz", BOARD, collector, warn=lambda _t: None,
                         period_s=0.01)
    store.start()
    running = started_since(before)
    # Names that say what each does.
    assert {"measure views", "track", "solve", "save session"} <= set(running), running
    live.offer(np.zeros((48, 64), np.uint8))
    track.offer(1)
    assert live.stop(timeout=5.0) and track.stop(timeout=5.0) and solver.close(timeout=5.0)
    store.close(timeout=5.0)
    left = [t.name for t in running.values() if t.is_alive()]
    assert left == [], f"still running after close: {left}"
    assert not (live.alive or track.alive or solver.alive or store.alive)
    assert started_since(before) == {}
    # Closing again is harmless and says the same.
    assert live.stop(0.0) and track.stop(0.0) and solver.close(0.0)


def test_stop_waits_for_the_thread_and_says_whether_it_ended() -> None:
    gate, inside = threading.Event(), threading.Event()

    def slow(_item: int) -> None:
        inside.set()
        gate.wait(10.0)

    track: LatestWorker[int] = LatestWorker(slow, lambda _e: None, name="track")
    track.offer(1)
    assert inside.wait(5.0)
    # The handler holds the thread: a short stop reports it still running ...
    assert track.stop(timeout=0.05) is False and track.alive
    gate.set()
    # ... and a second one joins it once the item in hand is done.
    assert track.stop(timeout=5.0) is True and not track.alive


def test_a_solve_comes_back_as_a_future(tmp_path: Path) -> None:
    params = load_params(PARAMS, {"output_file": str(tmp_path / "c.yaml")})
    with SolveWorker() as solver:
        good = solver.submit(views(12, seed=5), BOARD, CAM.size, params)
        refused = solver.submit(views(2, seed=4), BOARD, CAM.size, params)
        assert isinstance(good, Future)
        run = good.result(timeout=300)
        assert isinstance(run, SolveRun) and run.path == tmp_path / "c.yaml"
        # The true focal length back from 0.1 px noise, within 0.5 %.
        fx_true = CAM.K[0, 0]
        assert abs(run.result.camera_matrix[0, 0] - fx_true) < 0.005 * fx_true
        with pytest.raises(CalibrationError, match="at least 3"):
            refused.result(timeout=60)
    assert not solver.alive


def test_closing_the_worker_ends_a_solve_in_progress(tmp_path: Path) -> None:
    params = load_params(PARAMS, {"output_file": str(tmp_path / "c.yaml")})
    before = set(threading.enumerate())
    solver = SolveWorker()
    future = solver.submit(views(40, seed=6), BOARD, CAM.size, params)
    assert solver.close(timeout=60.0), "the solve thread outlived close()"
    assert started_since(before) == {}
    assert future.done()
    with pytest.raises(CancelledError):
        future.result()
    assert not (tmp_path / "c.yaml").exists()
    # A worker once closed takes no more work: the future says so at once.
    late = solver.submit(views(12, seed=5), BOARD, CAM.size, params)
    with pytest.raises(CancelledError):
        late.result(timeout=0)


def test_a_report_is_written_behind_the_solve_and_ends_when_the_worker_closes(
        tmp_path: Path) -> None:
    params = load_params(PARAMS, {"output_file": str(tmp_path / "c.yaml")})
    said: list[tuple[bool, str]] = []
    with SolveWorker() as solver:
        run = solver.submit(views(12, seed=5), BOARD, CAM.size, params).result(timeout=300)
        where = queue_report(solver, tmp_path / "report", run.result, views(12, seed=5),
                             BOARD, tone_curve=None, board_check=None, title="cam",
                             said=lambda ok, text: said.append((ok, text)))
        # the next job runs after the report: when it is done, so is the report
        solver.submit_task(lambda: None).result(timeout=300)
    assert said == [(True, f"report written: {where / 'report.pdf'}")]
    assert (where / "report.pdf").read_bytes().startswith(b"%PDF")
    # Closed while a report is being written: it stops at its next page, the old PDF stays.
    old = (where / "report.pdf").read_bytes()
    solver = SolveWorker()
    said.clear()
    started = threading.Event()
    solver.submit_task(started.set)
    queue_report(solver, where, run.result, views(12, seed=5), BOARD, tone_curve=None,
                 board_check=None, title="cam", said=lambda ok, text: said.append((ok, text)))
    assert started.wait(60)
    assert solver.close(timeout=30.0), "the report kept the solve thread past close()"
    assert said == [] and (where / "report.pdf").read_bytes() == old


def test_the_executor_spin_thread_is_joined_by_its_close() -> None:
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    from artcal_ros.ros.signals import ExecutorSpin

    context = Context()
    rclpy.init(args=[], context=context)
    try:
        before = set(threading.enumerate())
        spin = ExecutorSpin(SingleThreadedExecutor(context=context))
        assert "spin executor" in started_since(before)
        assert spin.close(timeout_s=5.0)
        assert started_since(before) == {}
    finally:
        rclpy.try_shutdown(context=context)
