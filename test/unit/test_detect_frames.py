"""A recording's frames detected on worker processes (core/detect/frames.py): every frame,
in order, the same results whatever the number of workers, corners where the renderer put
them."""

from __future__ import annotations

import numpy as np
import pytest

from artcal_ros import Board, Detector
from artcal_ros.core.detect.frames import detect_frames
from artcal_ros.synth import Camera, Photometry, RenderedView, random_poses, render_view

BOARD = Board()


@pytest.fixture(scope="module")
def views() -> list[RenderedView]:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(2207)
    return [render_view(BOARD, cam, r, t, rng=rng, photometry=Photometry.clean())
            for r, t in random_poses(BOARD, cam, 9, rng)]


def _frames(views: list[RenderedView]) -> list[tuple[str, np.ndarray]]:
    return [(f"frame{k}", v.image) for k, v in enumerate(views)]


def test_every_frame_is_detected_in_order_alike_on_one_or_two_workers(
        views: list[RenderedView]) -> None:
    # 2 warm-up frames here, then runs of 3 frames: three runs share two workers
    found = {w: list(detect_frames(_frames(views), Detector(BOARD), workers=w, warmup=2,
                                   run=3))
             for w in (1, 2)}
    one, two = found[1], found[2]
    assert [d.source for d in two] == [f"frame{k}" for k in range(len(views))]
    for a, b in zip(one, two, strict=True):
        assert np.array_equal(a.ids, b.ids)
        assert np.array_equal(a.corners_px, b.corners_px)  # bit for bit
    errors = []
    for d, v in zip(two, views, strict=True):
        assert len(d.ids) >= 0.9 * int(v.inside.sum()), d.source
        pos = np.searchsorted(v.ids, d.ids)
        errors.append(np.linalg.norm(d.corners_px - v.corners_px[pos], axis=2).ravel())
    # clean renders: the precise detector's corners are a few hundredths of a pixel off
    assert float(np.sqrt(np.mean(np.concatenate(errors) ** 2))) < 0.05


def test_the_warm_up_teaches_the_callers_detector_and_a_short_set_stays_in_process(
        views: list[RenderedView]) -> None:
    detector = Detector(BOARD)
    dets = list(detect_frames(_frames(views[:4]), detector, workers=2, warmup=2, run=3))
    assert len(dets) == 4
    assert detector.tone.sides > 0  # learnt from the two warm-up frames
    # a run is detected from the warm-up's state, as a plain Detector goes on from it
    plain = Detector(BOARD)
    alone = [plain.detect(image, source=name) for name, image in _frames(views[:4])]
    for a, b in zip(dets, alone, strict=True):
        assert np.array_equal(a.corners_px, b.corners_px)
