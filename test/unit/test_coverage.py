"""Coverage, view novelty, tilt and readiness (core.live.coverage), and the overlay pictures,
on exact projections of a known board through a known pinhole camera; the node's readiness
agrees with the solve's coverage warning; the collector under several threads at once."""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable

import cv2
import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.coverage import CoverageConfig, Snapshot, ViewCollector, empty_regions
from artcal_ros.core.live.overlay import render_heat_map, render_overlay
from artcal_ros.core.live.view_geometry import (
    COVERAGE_GRID,
    MIN_COVERAGE,
    grid_cells,
    solve_points,
    view_geometry,
)
from artcal_ros.synth import Camera, project_points

BOARD = Board(cols=8, rows=5)  # 0.62 x 0.38 m
SIZE = (640, 480)
PINHOLE = Camera("plumb_bob", np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]]),
                 np.zeros(5), SIZE)


def view(yaw_deg: float = 0.0, pitch_deg: float = 0.0, distance: float = 1.0,
         shift: tuple[float, float] = (0.0, 0.0)) -> Detections:
    """Exact detections of the board's markers wholly inside the image: the board centre
    ``distance`` m ahead (moved by ``shift`` m), turned by ``yaw`` about the camera's y axis
    and ``pitch`` about its x axis."""
    R_yaw, _ = cv2.Rodrigues(np.array([0.0, math.radians(yaw_deg), 0.0]))
    R_pitch, _ = cv2.Rodrigues(np.array([math.radians(pitch_deg), 0.0, 0.0]))
    R = R_pitch @ R_yaw
    w, h = BOARD.size_m
    center = np.array([w / 2, h / 2, 0.0])
    tvec = -R @ center + np.array([shift[0], shift[1], distance])
    rvec = cv2.Rodrigues(R)[0].ravel()
    corners = project_points(PINHOLE, BOARD.object_corners().reshape(-1, 3), rvec, tvec)
    corners = corners.reshape(-1, 4, 2)
    inside = np.all((corners >= 0) & (corners <= np.array(SIZE) - 1), axis=(1, 2))
    centers = project_points(PINHOLE, BOARD.object_centers(), rvec, tvec)
    return Detections(BOARD.ids[inside], corners[inside], centers[inside], SIZE)


@pytest.mark.parametrize(("yaw", "pitch"), [(0, 0), (30, 0), (-30, 0), (0, 25), (20, -20)])
def test_tilt_estimate_follows_the_pose(yaw: float, pitch: float) -> None:
    d = view(yaw, pitch)
    # The estimate assumes f = 0.8 x 640 = 512 where the truth is 600: a few degrees off at
    # most, far inside the 15 degree "tilted" threshold it serves.
    g = view_geometry(*solve_points(d, BOARD, "corners"), SIZE)
    assert abs(g.tilt_x_deg - yaw) < 5, g.tilt_x_deg
    assert abs(g.tilt_y_deg - pitch) < 5, g.tilt_y_deg
    assert abs(np.linalg.norm(g.normal) - 1) < 1e-9 and g.normal[2] < 0
    assert g.cells.shape == (COVERAGE_GRID[0] * COVERAGE_GRID[1],) and g.cells.any()


def test_a_view_is_kept_once_and_only_with_enough_markers() -> None:
    collector = ViewCollector(BOARD, CoverageConfig(min_markers=6))
    frontal = view()
    assert collector.add(frontal)
    assert not collector.add(frontal), "the same view twice"
    # Moved by 5 mm at 1 m: ~3 px, below the 3% of the diagonal (24 px) that makes it new.
    assert not collector.add(view(shift=(0.005, 0.0)))
    assert collector.add(view(shift=(0.08, 0.0)))
    assert collector.add(view(yaw_deg=30))
    assert not collector.add(frontal.subset(np.arange(5))), "5 markers < min_markers"
    assert len(collector.views) == 3


def test_readiness_says_what_is_missing_until_it_is_ready() -> None:
    collector = ViewCollector(BOARD, CoverageConfig(min_views=4))
    collector.add(view(distance=2.5))  # small, frontal, in the middle
    r = collector.readiness()
    assert not r.ready and not r.enough_views
    assert r.missing[0] == "3 more views"
    assert any("top-left" in m and "bottom-right" in m for m in r.missing)
    assert "centre" not in empty_regions(collector.counts())
    assert any("left or right" in m for m in r.missing)
    assert any("up or down" in m for m in r.missing)
    for yaw, pitch, shift in [(30, 0, (-0.25, -0.1)), (-30, 0, (0.25, 0.1)),
                              (0, 30, (0.25, -0.15)), (0, -30, (-0.25, 0.15)),
                              (20, 20, (0.0, 0.0))]:
        collector.add(view(yaw, pitch, distance=1.1, shift=shift))
    r = collector.readiness()
    assert r.enough_views and r.ready, r.summary()
    assert r.coverage >= MIN_COVERAGE and r.tilted_lr >= 2 and r.tilted_ud >= 2
    collector.reset()
    assert collector.readiness().views == 0 and collector.coverage() == 0.0


def test_a_new_image_size_starts_a_fresh_collection() -> None:
    collector = ViewCollector(BOARD)
    collector.add(view())
    other = view(yaw_deg=30)
    resized = Detections(other.ids, other.corners_px, other.centers_px, (800, 600))
    assert collector.add(resized)
    assert len(collector.views) == 1 and collector.image_size == (800, 600)


def test_pictures() -> None:
    collector = ViewCollector(BOARD)
    d = view()
    collector.add(d)
    image = np.full((SIZE[1], SIZE[0]), 128, np.uint8)
    picture = render_overlay(image, d, collector.counts(), collector.readiness(), kept=True)
    assert picture.shape == (480, 640, 3) and picture.dtype == np.uint8
    x, y = np.round(d.corners_px[0, 1]).astype(int)  # a quad's corner is drawn green
    assert picture[y, x, 1] > 150 and picture[y, x, 2] < 150
    heat = render_heat_map(collector.counts(), SIZE)
    assert heat.shape == (240, 320, 3)
    assert not heat[:5, :5].any(), "uncovered corner cells are black"
    assert heat[120, 160].any(), "the covered centre is coloured"
    assert not render_heat_map(np.zeros(COVERAGE_GRID[::-1], np.int64), SIZE).any()


# --- one view geometry: the node's readiness and the solve's coverage warning agree ------

def seeded_views(seed: int) -> list[Detections]:
    """Six exact views of BOARD from one random distance, spread and tilts (seeded)."""
    rng = np.random.default_rng(seed)
    distance, spread = rng.uniform(1.0, 2.2), rng.uniform(0.2, 0.6)
    views = [view(rng.uniform(-30, 30), rng.uniform(-30, 30), distance=distance,
                  shift=(rng.uniform(-spread, spread), rng.uniform(-0.75, 0.75) * spread))
             for _ in range(6)]
    return [v for v in views if len(v) >= 6]


def assert_readiness_matches_the_solve(collector: ViewCollector, points: str) -> Snapshot:
    """Solve from the collector's views as the node does; the two must agree on coverage."""
    snap = collector.snapshot()
    assert snap.image_size is not None
    result = calibrate(snap.views, collector.board, image_size=snap.image_size, points=points,
                       cross_validation_folds=0)
    warned = [w for w in result.warnings if "cover only" in w]
    missing = [m for m in snap.readiness.missing if m.startswith("coverage")]
    assert snap.readiness.coverage == pytest.approx(result.coverage, abs=1e-12)
    assert bool(warned) == bool(missing), (snap.readiness.summary(), result.warnings)
    if snap.readiness.ready:
        assert not warned, "the node said ready, the solve warns about coverage"
    return snap


# Coverage near the threshold. With the old two geometries (the node: a 12 x 9 grid over
# the corners; the solve: 8 x 6 over its points) seed 7 was "coverage missing" in the node
# and fine in the solve (corners), seed 78 "ready" in the node and warned in the solve
# (centers); 20 and 195 straddle the threshold between the modes, 0 and 3 are far from it.
@pytest.mark.parametrize("points", ["corners", "centers"])
@pytest.mark.parametrize("seed", [7, 78, 20, 195, 0, 3])
def test_node_readiness_and_the_solve_agree_on_coverage(seed: int, points: str) -> None:
    collector = ViewCollector(BOARD, CoverageConfig(min_views=3, points=points))
    for d in seeded_views(seed):
        collector.add(d)
    assert_readiness_matches_the_solve(collector, points)


def test_a_realistic_ready_collection_gets_no_coverage_warning() -> None:
    """The webcam preset (real distortion, a 19 x 9 board, partial views) as the renderer
    poses it; true marker positions, the renderer's own truth."""
    from artcal_ros.synth import marker_truth, random_poses

    board = Board()
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(11)
    collector = ViewCollector(board, CoverageConfig(min_views=10))
    for rvec, tvec in random_poses(board, cam, 14, rng):
        corners, centers, inside, _ = marker_truth(board, cam, rvec, tvec)
        collector.add(Detections(board.ids[inside], corners[inside], centers[inside], cam.size))
    snap = assert_readiness_matches_the_solve(collector, "corners")
    assert snap.readiness.ready, snap.readiness.summary()


# --- thread safety ----------------------------------------------------------------------

def test_collector_under_concurrent_add_reset_and_queries() -> None:
    """Adders (two image sizes), a resetter and readers at once: every look is consistent."""
    other_size = (800, 600)
    pool = [view(yaw, pitch, distance=dist, shift=shift)
            for yaw in (-30, 0, 30) for pitch in (-25, 0, 25)
            for dist, shift in ((1.1, (0.0, 0.0)), (1.6, (0.2, 0.1)), (1.6, (-0.2, -0.1)))]
    resized = [Detections(d.ids, d.corners_px, d.centers_px, other_size) for d in pool[::3]]
    cfg = CoverageConfig(min_views=5, max_stored=6)
    collector = ViewCollector(BOARD, cfg)
    errors: list[BaseException] = []
    stop = threading.Event()
    looks = [0]

    def guarded(work: Callable[[], object]) -> Callable[[], None]:
        def run() -> None:
            try:
                while not stop.is_set():
                    work()
            except BaseException as e:  # reported by the main thread
                errors.append(e)
                stop.set()
        return run

    def add(seed: int) -> Callable[[], bool]:
        rng = np.random.default_rng(seed)
        return lambda: collector.add(
            resized[rng.integers(len(resized))] if rng.random() < 0.1
            else pool[rng.integers(len(pool))])

    def check() -> None:
        snap = collector.snapshot()
        n = len(snap.views)
        assert n <= cfg.max_stored
        assert snap.readiness.views == n
        if n == 0 or snap.image_size is None:
            assert n == 0 and snap.image_size is None and not snap.counts.any()
        else:
            # One size only, and the counts are exactly those of the views kept.
            size = snap.image_size
            assert {tuple(v.image_size) for v in snap.views} == {size}
            cells = np.sum([grid_cells(solve_points(v, BOARD, cfg.points)[1], size)
                            for v in snap.views], axis=0)
            np.testing.assert_array_equal(snap.counts.reshape(-1), cells)
        assert len(collector.views) <= cfg.max_stored
        collector.readiness()
        looks[0] += 1

    def reset() -> None:
        collector.reset()
        time.sleep(0.002)

    workers = [guarded(add(1)), guarded(add(2)), guarded(add(3)), guarded(reset),
               guarded(check), guarded(check)]
    threads = [threading.Thread(target=w) for w in workers]
    old_interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)  # switch threads often: races show up in a second
    try:
        for t in threads:
            t.start()
        stop.wait(1.5)
        stop.set()
        for t in threads:
            t.join(10)
    finally:
        sys.setswitchinterval(old_interval)
    assert not any(t.is_alive() for t in threads), "a thread hung (deadlock?)"
    assert not errors, repr(errors[0])
    assert looks[0] > 10
    # Still a working collection afterwards; a new size starts a fresh one.
    collector.reset()
    assert collector.add(pool[0]) and collector.add(resized[1])
    snap = collector.snapshot()
    assert len(snap.views) == 1 and snap.image_size == other_size


def test_counters_lose_no_count_across_threads() -> None:
    from artcal_ros.ros.diagnostics import Counters

    counters = Counters()
    per_thread = 20_000
    reports: list[int] = []

    def bump() -> None:
        for _ in range(per_thread):
            counters.frame_seen()
            counters.frame_broken()

    def report() -> None:
        for _ in range(500):
            r = counters.report()
            reports.append(r.new_broken)

    threads = [threading.Thread(target=bump) for _ in range(4)] + [threading.Thread(target=report)]
    old_interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-5)
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
    finally:
        sys.setswitchinterval(old_interval)
    final = counters.report()
    assert final.seen == final.broken == 4 * per_thread
    # Every broken frame is reported as new exactly once.
    assert sum(reports) + final.new_broken == 4 * per_thread


def test_overlay_is_scaled_down_to_its_max_width() -> None:
    cam = Camera("plumb_bob", np.array([[1400.0, 0, 959.5], [0, 1400.0, 539.5], [0, 0, 1]]),
                 np.zeros(5), (1920, 1080))
    rvec, tvec = np.array([0.1, -0.2, 0.0]), np.array([-0.6, -0.3, 1.6])
    corners = project_points(cam, BOARD.object_corners().reshape(-1, 3), rvec, tvec)
    centers = project_points(cam, BOARD.object_centers(), rvec, tvec)
    dets = Detections(BOARD.ids, corners.reshape(-1, 4, 2), centers, cam.size)
    snap = ViewCollector(BOARD, CoverageConfig(min_views=3)).snapshot()
    frame = np.full((1080, 1920), 255, np.uint8)
    small = render_overlay(frame, dets, snap.counts, snap.readiness, max_width=960)
    full = render_overlay(frame, dets, snap.counts, snap.readiness)
    assert small.shape == (540, 960, 3) and full.shape == (1080, 1920, 3)
    assert render_overlay(frame[:100, :200], None, snap.counts, snap.readiness,
                          max_width=960).shape == (100, 200, 3)
    # the marker outlines land where the detections are, at the smaller scale
    drawn = np.argwhere((small[..., 1] > 150) & (small[..., 0] < 100) & (small[..., 2] < 100))
    x0, y0 = (corners.min(axis=0) + 0.5) / 2 - 0.5
    x1, y1 = (corners.max(axis=0) + 0.5) / 2 - 0.5
    assert drawn[:, 1].min() >= x0 - 3 and drawn[:, 1].max() <= x1 + 3
    assert drawn[:, 0].min() >= y0 - 3 and drawn[:, 0].max() <= y1 + 3
