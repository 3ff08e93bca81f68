"""The live solve against the truth: its projection uncertainty predicts the actual error of
the camera it solved, warm-started updates agree with a cold solve of the same views, the
thread never makes its caller wait, and readiness follows the uncertainty."""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.coverage import CoverageConfig, ViewCollector
from artcal_ros.core.live.live_solve import MAX_DEFER_S, LiveSolve, LiveSolver
from artcal_ros.core.live.readiness import (
    calibrate_readiness,
    live_readiness,
    not_solved_text,
    uncertainty_text,
)
from artcal_ros.synth import Camera
from test.unit.noisy_views import BOARD, noisy_views

CAM = Camera.preset("webcam")


def with_sigmas(dets: list[Detections], sigma_px: float) -> list[Detections]:
    """The views with the detector's 1-sigma of every corner set (a weighted solve)."""
    return [replace(d, corner_sigma_px=np.full((len(d), 4), sigma_px)) for d in dets]


def test_uncertainty_predicts_the_actual_error_over_sessions() -> None:
    # E[projection difference^2] = uncertainty^2 for an honest 1-sigma: over 12 sessions
    # the ratio of their RMS is near 1 (a factor 1.5 either way is far outside chance for
    # 12 sessions; a covariance not scaled by the measured noise is off by the noise ratio).
    true_sq, unc_sq = [], []
    for seed in range(12):
        noise = 0.02 if seed % 2 else 0.06
        dets = with_sigmas(noisy_views(CAM, 12, 900 + seed, noise), 0.03)
        est = LiveSolver(BOARD).update(dets, CAM.size)
        assert est is not None and est.n_views == 12
        true_sq.append(projection_difference(CAM, est.camera)[0] ** 2)
        unc_sq.append(est.uncertainty_rms_px ** 2)
        # the sigmas given are off by 1.5-2 x: the measured residuals set the scale
        assert 0.5 < est.reprojection_rms_px / (noise * np.sqrt(2)) < 1.5
    ratio = float(np.sqrt(np.mean(true_sq) / np.mean(unc_sq)))
    assert 1 / 1.5 < ratio < 1.5, ratio
    noisy = np.mean(unc_sq[0::2]) ** 0.5 / np.mean(unc_sq[1::2]) ** 0.5
    assert 2.0 < noisy < 4.5, noisy  # three times the noise, three times the uncertainty


def test_warm_updates_agree_with_a_cold_solve() -> None:
    dets = with_sigmas(noisy_views(CAM, 16, 77, 0.03), 0.03)
    warm = LiveSolver(BOARD)
    est = None
    for n in range(3, 17):
        est = warm.update(dets[:n], CAM.size)
    assert est is not None and est.warm and est.collected == 16
    cold = LiveSolver(BOARD).update(dets, CAM.size)
    assert cold is not None and not cold.warm
    apart, _ = projection_difference(cold.camera, est.camera)
    # the same minimum: far closer than the uncertainty of either
    assert apart < 0.05 * cold.uncertainty_rms_px, (apart, cold.uncertainty_rms_px)
    assert abs(est.uncertainty_rms_px / cold.uncertainty_rms_px - 1) < 0.02


def test_two_views_are_solved_with_an_honest_uncertainty() -> None:
    # Two tilted views fix the focal lengths and principal point: the live solve answers from
    # the second view, and its uncertainty already matches its error (one draw each).
    ratios = []
    for seed in range(12):
        est = LiveSolver(BOARD).update(noisy_views(CAM, 2, seed), CAM.size)
        assert est is not None and est.n_views == 2
        ratios.append(projection_difference(CAM, est.camera)[0] / est.uncertainty_rms_px)
    assert all(0.25 < r < 3.0 for r in ratios), ratios
    assert 0.6 < float(np.median(ratios)) < 1.5, ratios


def test_the_words_before_the_first_solve() -> None:
    assert uncertainty_text(None, 1) == "not yet (1 view)"
    assert uncertainty_text(None, 0) == "not yet (0 views)"
    assert not_solved_text(1) == "not yet (1 view, needs 2 to solve)"
    assert not_solved_text(2) == "not yet (2 views, solving)"


def test_a_reset_collection_starts_cold() -> None:
    solver = LiveSolver(BOARD)
    first = noisy_views(CAM, 6, 5)
    assert solver.update(first[:1], CAM.size) is None  # too few to solve
    assert solver.update(first, CAM.size) is not None
    other = noisy_views(CAM, 5, 6)
    est = solver.update(other, CAM.size)
    assert est is not None and not est.warm and est.collected == 5


def test_the_thread_takes_the_newest_collection_and_never_blocks() -> None:
    dets = with_sigmas(noisy_views(CAM, 14, 31), 0.03)
    updates: list[int] = []
    live = LiveSolve(BOARD, on_update=lambda e: updates.append(e.collected))
    try:
        slowest = 0.0
        for n in range(1, 15):
            t0 = time.monotonic()
            live.offer(dets[:n], CAM.size)
            slowest = max(slowest, time.monotonic() - t0)
        assert slowest < 0.05, slowest  # a hand-over, not a solve
        deadline = time.monotonic() + 60
        while (live.busy or not updates or updates[-1] != 14) and time.monotonic() < deadline:
            time.sleep(0.02)
        snap = live.snapshot()
        assert snap is not None and snap.collected == 14 and snap.n_views == 14
        assert len(updates) < 14  # collections offered during a solve were skipped
        assert projection_difference(CAM, snap.camera)[0] < 5 * snap.uncertainty_rms_px
        live.reset()
        assert live.snapshot() is None
    finally:
        assert live.stop(timeout=10.0)
    assert not live.alive


def test_an_update_waits_while_views_wait_for_precise_detection() -> None:
    # The node's precise detection comes first: an offer waits while it is busy, at most
    # MAX_DEFER_S, and goes at once when it is idle.
    dets = with_sigmas(noisy_views(CAM, 6, 33), 0.03)
    busy = [True]
    done: list[float] = []
    live = LiveSolve(BOARD, on_update=lambda e: done.append(time.monotonic()),
                     defer_while=lambda: busy[0])
    try:
        t0 = time.monotonic()
        live.offer(dets, CAM.size)
        deadline = t0 + 60
        while not done and time.monotonic() < deadline:
            time.sleep(0.02)
        assert done and done[0] - t0 >= MAX_DEFER_S, "solved before the deferral ran out"
        busy[0] = False
        t1 = time.monotonic()
        live.offer(dets[:5], CAM.size)
        while len(done) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert len(done) == 2
        # not held back: the solve starts within a poll (its own time aside)
        snap = live.snapshot()
        assert snap is not None and done[1] - t1 < 1.0 + snap.seconds
    finally:
        assert live.stop(timeout=10.0)


def test_readiness_follows_the_uncertainty() -> None:
    collector = ViewCollector(BOARD, CoverageConfig(min_views=8))
    dets = with_sigmas(noisy_views(CAM, 12, 41), 0.03)
    for d in dets:
        collector.add(d)
    snap = collector.snapshot()
    assert snap.readiness.views >= 8
    before = live_readiness(snap.readiness, None, 0.1)
    assert not before.ready and any("not yet" in m for m in before.missing)
    est = LiveSolver(BOARD).update(snap.views, CAM.size)
    assert est is not None
    u = est.uncertainty_rms_px
    strict = live_readiness(snap.readiness, est, 0.5 * u)
    assert not strict.ready
    assert f"projection uncertainty {u:.3g} px, needs <= {0.5 * u:.3g} px" in strict.missing
    assert live_readiness(snap.readiness, est, 2 * u).ready
    few = replace(snap.readiness, views=5)
    assert live_readiness(few, est, 2 * u).missing == ("3 more views",)
    assert calibrate_readiness(u, 12, 8, 2 * u).startswith("ready")
    assert "2.0 x the bound" in calibrate_readiness(u, 12, 8, 0.5 * u)


def test_live_status_says_the_uncertainty_and_the_next_pose() -> None:
    from artcal_ros.core.live.live_status import LiveStatus
    from artcal_ros.core.params import load_params

    params = load_params(Path(__file__).resolve().parents[2] / "config" / "calibrator.yaml")
    collector = ViewCollector(BOARD, CoverageConfig(min_views=10))
    dets = with_sigmas(noisy_views(CAM, 12, 52), 0.03)
    for d in dets:
        collector.add(d)
    status = LiveStatus(BOARD, params)
    try:
        snap = collector.snapshot()
        first = status.diagnostics(snap.readiness)
        assert first["projection uncertainty"] == f"not yet ({snap.readiness.views} views)"
        assert first["next pose"] == "after the first view"
        status.offer(snap)
        deadline = time.monotonic() + 60
        while status.suggestion is None and time.monotonic() < deadline:
            time.sleep(0.02)
        est, suggestion = status.estimate, status.suggestion
        assert est is not None and suggestion is not None
        values = status.diagnostics(snap.readiness)
        assert values["projection uncertainty"].startswith(f"{est.uncertainty_rms_px:.3f} px")
        assert values["next pose"] == suggestion.text
        # the suggestion is expected to lower the uncertainty it was chosen against
        assert suggestion.uncertainty_rms_px < suggestion.current_uncertainty_rms_px
        overlay = np.zeros((480, 640, 3), np.uint8)
        status.draw(overlay, 640, Detections.empty(CAM.size))
        assert overlay.any(), "the outline is drawn"
        status.reset()
        assert status.suggestion is None and status.estimate is None
    finally:
        assert status.stop(10.0)


def test_a_wrong_start_is_refused_and_does_not_stick() -> None:
    # The fisheye's first 3-5 views of this session fit only a wrong minimum (21-35 px):
    # refused, and the next update starts cold instead of from it.
    from artcal_ros.core.errors import CalibrationError
    from artcal_ros.core.live.live_solve import LiveSolveConfig

    fisheye = Camera.preset("fisheye")
    dets = with_sigmas(noisy_views(fisheye, 15, 21), 0.03)
    solver = LiveSolver(BOARD, LiveSolveConfig(model="equidistant"))
    refused, est = 0, None
    for n in range(3, 16):
        try:
            est = solver.update(dets[:n], fisheye.size)
        except CalibrationError as e:
            assert "px RMS" in str(e)
            refused += 1
    assert refused >= 1 and est is not None and est.collected == 15
    assert est.reprojection_rms_px < 0.1
    assert projection_difference(fisheye, est.camera)[0] < 4 * est.uncertainty_rms_px
