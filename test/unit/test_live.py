"""The live stream's two tiers (core.live.tracking, core.live.stream) and the collector's held
views, on rendered hand-held sweeps whose every true corner is known."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable

import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.coverage import CoverageConfig, ViewCollector
from artcal_ros.core.live.stream import LiveConfig, LiveDetection
from artcal_ros.core.live.tracking import MarkerTracker
from artcal_ros.synth import Camera, Photometry, RenderedView, render_view, smooth_poses

BOARD = Board()


@pytest.fixture(scope="module")
def sweep() -> list[RenderedView]:
    """16 frames of a 640 x 480 hand-held sweep: 4 px of motion a frame, growing to 35 px
    at frame 8 and 130 px (a fifth of the image) at frame 14."""
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(5)
    poses = smooth_poses(BOARD, cam, 16, rng, frames_per_key=15)
    return [render_view(BOARD, cam, r, t, photometry=Photometry.clean(), rng=rng)
            for r, t in poses]


@pytest.fixture(scope="module")
def precise(sweep: list[RenderedView]) -> list[Detections]:
    detector = Detector(BOARD)
    return [detector.detect(v.image) for v in sweep]


def corner_errors(dets: Detections, view: RenderedView) -> np.ndarray:
    """(N,) largest corner error of each detected marker against the truth, pixels."""
    pos = np.searchsorted(view.ids, dets.ids)
    assert np.array_equal(view.ids[pos], dets.ids)
    return np.asarray(np.linalg.norm(dets.corners_px - view.corners_px[pos], axis=2).max(axis=1))


def test_tracked_markers_follow_the_board(sweep: list[RenderedView],
                                          precise: list[Detections]) -> None:
    tracker = MarkerTracker(BOARD)
    index, first = tracker.track(sweep[0].image)
    assert len(first) == 0  # nothing is known before a seed
    assert tracker.seed(index, precise[0]) == len(precise[0])
    kept, worst = [], []
    for view in sweep[1:9]:  # up to 35 px of motion a frame
        _, dets = tracker.track(view.image)
        err = corner_errors(dets, view)
        kept.append(len(dets) / len(precise[0]))
        worst.append(err.max() / np.median(view.side_px[view.inside]))
        assert np.median(err) < 1.0
        assert np.isnan(dets.corner_sigma_px).all()  # never mistaken for precise points
    # no marker is ever near a whole marker away from where it truly is (a wrong id)
    assert max(worst) < 0.4, worst
    assert np.mean(kept) > 0.6, kept
    for view in sweep[9:]:  # faster and faster: markers are lost, none is misplaced
        _, dets = tracker.track(view.image)
        assert (corner_errors(dets, view) < 0.5 * np.median(view.side_px[view.inside])).all()


def test_an_old_seed_is_carried_to_the_newest_frame(sweep: list[RenderedView],
                                                    precise: list[Detections]) -> None:
    tracker = MarkerTracker(BOARD)
    indices = [tracker.track(v.image)[0] for v in sweep[:5]]
    # the detections of frame 0 arrive when frame 4 is the newest
    reached = tracker.seed(indices[0], precise[0])
    assert reached > 0.6 * len(precise[0])
    _, dets = tracker.track(sweep[5].image)
    err = corner_errors(dets, sweep[5])
    assert len(dets) > 0.6 * len(precise[0])
    assert np.median(err) < 1.0 and err.max() < 0.4 * np.median(sweep[5].side_px)


def test_markers_are_lost_not_renamed_when_the_board_leaves(
        sweep: list[RenderedView], precise: list[Detections]) -> None:
    tracker = MarkerTracker(BOARD)
    index, _ = tracker.track(sweep[0].image)
    tracker.seed(index, precise[0])
    rng = np.random.default_rng(1)
    clutter = rng.integers(0, 255, sweep[0].image.shape, dtype=np.uint8)
    _, gone = tracker.track(clutter)
    assert len(gone) <= 2  # noise cannot carry a neighbourhood along
    _, after = tracker.track(np.full_like(sweep[0].image, 128))
    assert len(after) == 0


def test_a_new_image_size_forgets_everything(sweep: list[RenderedView],
                                             precise: list[Detections]) -> None:
    tracker = MarkerTracker(BOARD)
    index, _ = tracker.track(sweep[0].image)
    tracker.seed(index, precise[0])
    _, other = tracker.track(np.zeros((240, 320), np.uint8))
    assert len(other) == 0 and other.image_size == (320, 240)
    assert tracker.seed(index, precise[0]) == 0  # that frame is forgotten


def test_held_views_settle_release_and_reset(precise: list[Detections]) -> None:
    collector = ViewCollector(BOARD, CoverageConfig(min_views=2))
    first = collector.reserve(precise[0])
    assert first is not None and collector.pending == 1
    assert collector.reserve(precise[0]) is None  # the same view is already held
    assert collector.snapshot().views == []       # a held view is no view yet
    assert collector.settle(first, precise[0])
    assert collector.pending == 0 and len(collector.views) == 1
    second = collector.reserve(precise[8])
    assert second is not None
    collector.release(second)
    assert collector.pending == 0 and len(collector.views) == 1
    third = collector.reserve(precise[8])
    assert third is not None
    collector.reset()
    assert not collector.settle(third, precise[8])  # reset in between: nothing kept
    assert collector.views == []


def run_stream(live: LiveDetection, views: list[RenderedView], period_s: float) -> list[int]:
    markers = []
    for view in views:
        markers.append(len(live.offer(view.image).markers))
        time.sleep(period_s)
    assert live.wait_idle(timeout=60.0)
    return markers


def test_only_precise_detections_become_views(sweep: list[RenderedView],
                                              precise: list[Detections]) -> None:
    collector = ViewCollector(BOARD)
    measured: list[Detections] = []
    live = LiveDetection(BOARD, Detector(BOARD).detect, collector,
                         LiveConfig(refresh_s=0.0),
                         on_measured=lambda image, dets, kept: measured.append(dets))
    try:
        run_stream(live, sweep[:9], 0.05)
        # the camera comes to rest: the fast tier soon shows the board's markers
        deadline = time.monotonic() + 30.0
        shown = 0
        while shown < 0.8 * len(precise[8]) and time.monotonic() < deadline:
            shown = len(live.offer(sweep[8].image).markers)
            time.sleep(0.05)
        assert shown >= 0.8 * len(precise[8])
        assert live.wait_idle(timeout=30.0)
    finally:
        live.stop()
    views = collector.views
    assert len(views) >= 2
    assert all(v.source != "tracked" and np.isfinite(v.corner_sigma_px).any() for v in views)
    assert live.counts().measured == len(measured) >= len(views)
    assert collector.pending == 0


def test_a_full_queue_refuses_views_and_loses_nothing_else(
        sweep: list[RenderedView], precise: list[Detections]) -> None:
    gate = threading.Event()
    by_image = {id(v.image): d for v, d in zip(sweep, precise, strict=True)}

    def slow_detect(image: np.ndarray) -> Detections:
        gate.wait(30.0)  # precise detection held up until the stream is over
        return by_image[id(image)]

    collector = ViewCollector(BOARD)
    live = LiveDetection(BOARD, slow_detect, collector, LiveConfig(max_queued=2))
    try:
        tracker_seed: Callable[[], None] = lambda: live.tracker.seed(  # noqa: E731
            live.tracker.track(sweep[0].image)[0], precise[0])
        tracker_seed()
        for view in sweep[1:]:
            live.offer(view.image)
        counts = live.counts()
        assert counts.queued <= 3  # two queued, one in detection (the first's refresh)
        assert counts.refused >= 1
        gate.set()
        assert live.wait_idle(timeout=30.0)
    finally:
        gate.set()
        live.stop()
    assert collector.pending == 0
    # the two queued, the one in detection and one refresh of the newest frame at most
    assert 1 <= len(collector.views) <= 4


def test_a_detection_running_across_a_reset_adds_nothing(
        sweep: list[RenderedView], precise: list[Detections]) -> None:
    started, gate = threading.Event(), threading.Event()

    def slow_detect(image: np.ndarray) -> Detections:
        started.set()
        gate.wait(30.0)
        return precise[0]

    collector = ViewCollector(BOARD)
    live = LiveDetection(BOARD, slow_detect, collector, LiveConfig(refresh_s=0.0))
    try:
        live.offer(sweep[0].image)  # the newest frame: measured as soon as the tier is idle
        assert started.wait(30.0)
        live.reset()
        collector.reset()
        gate.set()
        deadline = time.monotonic() + 30.0
        while live.counts().measured < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert live.counts().measured >= 1
    finally:
        gate.set()
        live.stop()
    assert collector.views == []  # the view it measured belonged to the collection before
