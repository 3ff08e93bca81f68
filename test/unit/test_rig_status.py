"""A live rig's readiness from each camera's live solve, against the renderer's rig: not ready
with too few rig views or an uncertainty over the bound, ready when every camera's is under
it, each camera's uncertainty near its true projection difference, and the live solves'
threads joined by their owner."""

from __future__ import annotations

import re
import threading
import time
from pathlib import Path

import numpy as np

from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.rig_status import RigReadiness, RigStatus, camera_views
from artcal_ros.core.live.rig_views import RigSnapshot, RigViews, RigViewsConfig
from artcal_ros.core.params import load_params
from test.unit.rig_synth import BOARD, make_rig

ROOT = Path(__file__).resolve().parents[2]
MIN_VIEWS = 8


def params(max_uncertainty: float = 0.1) -> dict[str, object]:
    return dict(load_params(ROOT / "config" / "calibrator.yaml",
                            {"min_views": MIN_VIEWS,
                             "readiness.max_uncertainty": max_uncertainty}))


def collect(names: tuple[str, ...], dets: dict[str, list[Detections]], frames: int
            ) -> RigSnapshot:
    views = RigViews(BOARD, names, RigViewsConfig(min_views=MIN_VIEWS))
    for k in range(frames):
        views.add({n: dets[n][k] for n in names})
    return views.snapshot()


def solved(status: RigStatus, snap: RigSnapshot, timeout: float = 60.0) -> RigReadiness:
    """The readiness once every camera's live solve has solved all its views."""
    deadline = time.monotonic() + timeout
    while True:
        ready = status.readiness(snap)
        if all(c.estimate is not None and c.estimate.collected == c.views
               for c in ready.cameras.values()):
            return ready
        assert time.monotonic() < deadline, ready.summary()
        time.sleep(0.05)


def test_too_few_rig_views_is_not_ready_whatever_the_uncertainty() -> None:
    rig, dets = make_rig("stereo", "webcam", 5, 11, noise_px=0.03)
    snap = collect(rig.names, dets, 5)
    status = RigStatus(BOARD, rig.names, params(max_uncertainty=100.0))
    try:
        assert not status.readiness(snap).ready  # before any estimate
        assert "left: projection uncertainty not yet" in status.readiness(snap).summary()
        status.offer(snap)
        ready = solved(status, snap)
        assert not ready.ready
        assert ready.missing == (f"{MIN_VIEWS - len(snap.views)} more rig views (the board "
                                 "seen by two or more cameras at once)",), ready.missing
        # each camera's live solve took its own views of the rig views
        for n in rig.names:
            assert ready.cameras[n].estimate.collected == len(snap.views)  # type: ignore[union-attr]
    finally:
        assert status.stop(5.0) == []


def test_ready_when_every_camera_is_within_the_bound_and_honest_against_truth() -> None:
    true_sq, unc_sq = [], []
    for seed in range(4):
        rig, dets = make_rig("stereo", "webcam", 20, 100 + seed, noise_px=0.03)
        snap = collect(rig.names, dets, 20)
        assert snap.enough
        status = RigStatus(BOARD, rig.names, params(max_uncertainty=0.1))
        try:
            status.offer(snap)
            ready = solved(status, snap)
            for n in rig.names:
                estimate = ready.cameras[n].estimate
                assert estimate is not None
                true = projection_difference(rig.camera(n), estimate.camera)[0]
                # one session's ratio spreads (a few directions of the intrinsics dominate)
                assert 1 / 6 < true / estimate.uncertainty_rms_px < 6, (n, true, estimate)
                true_sq.append(true ** 2)
                unc_sq.append(estimate.uncertainty_rms_px ** 2)
            # 0.03 px corners, 20 views of a 70-marker board: well under 0.1 px
            assert ready.ready, ready.summary()
            assert ready.summary().endswith("; ready")
            if seed == 0:
                worst = max(c.estimate.uncertainty_rms_px  # type: ignore[union-attr]
                            for c in ready.cameras.values())
                # a bound under the worst camera's uncertainty: not ready, that camera named
                status.reconfigure(params(max_uncertainty=0.9 * worst))
                tight = status.readiness(snap)
                assert not tight.ready
                assert any(m.startswith(tuple(f"{n}: projection uncertainty" for n in rig.names))
                           and "needs <=" in m for m in tight.missing), tight.missing
                per_camera, rig_values = status.diagnostics(snap, tight)
                for n in rig.names:
                    assert re.fullmatch(r"\d\.\d{3} px RMS, max \d\.\d{3} px \(\d+ views\)",
                                        per_camera[n]["projection uncertainty"]), per_camera[n]
                    assert rig_values[f"{n}: projection uncertainty"] == \
                        per_camera[n]["projection uncertainty"]
                # the next pose follows each estimate on the same thread
                deadline = time.monotonic() + 30.0
                while not all(s.suggestion for s in status.cameras.values()):
                    assert time.monotonic() < deadline, "no next pose"
                    time.sleep(0.05)
                per_camera, _ = status.diagnostics(snap, tight)
                for n in rig.names:
                    assert per_camera[n]["next pose"] == status.cameras[n].suggestion.text  # type: ignore[union-attr]
        finally:
            assert status.stop(5.0) == []
    ratio = float(np.sqrt(np.mean(true_sq) / np.mean(unc_sq)))
    # an honest 1-sigma: the RMS of the true differences near the RMS of the uncertainties
    assert 0.5 < ratio < 2.0, ratio


def test_each_camera_solves_only_the_views_it_measures_and_forgets_a_reset() -> None:
    rig, dets = make_rig("trio", "webcam", 24, 7, noise_px=0.03, partial_fraction=0.5)
    views = RigViews(BOARD, rig.names, RigViewsConfig(min_views=MIN_VIEWS))
    for k in range(24):
        views.add({n: dets[n][k] for n in rig.names})
    snap = views.snapshot()
    counts = {n: len(camera_views(snap, n)) for n in rig.names}
    assert len(set(counts.values())) > 1, counts  # the cameras measure different views
    status = RigStatus(BOARD, rig.names, params())
    try:
        status.offer(snap)
        ready = solved(status, snap)
        for n in rig.names:
            assert ready.cameras[n].estimate.collected == counts[n]  # type: ignore[union-attr]
        # the views forgotten (as a new image size does): no camera keeps its old figures
        views.reset()
        empty = views.snapshot()
        after = status.readiness(empty)
        assert all(c.estimate is None for c in after.cameras.values())
        assert not after.ready
    finally:
        assert status.stop(5.0) == []


def test_the_live_solves_threads_are_joined_by_stop() -> None:
    before = set(threading.enumerate())
    rig, dets = make_rig("stereo", "webcam", 10, 3, noise_px=0.03)
    status = RigStatus(BOARD, rig.names, params())
    running = [t for t in threading.enumerate() if t not in before]
    assert sorted(t.name for t in running) == ["live solve", "live solve"], running
    status.offer(collect(rig.names, dets, 10))  # an update in flight finishes first
    assert status.stop(10.0) == []
    assert not any(t.is_alive() for t in running)
    assert status.stop(0.0) == []  # again: harmless
