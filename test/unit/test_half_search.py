"""The candidate search at half resolution (DetectorConfig.half_search_above_px)."""

from __future__ import annotations

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, DetectorConfig
from artcal_ros.core.detect.candidates import half_image
from artcal_ros.synth import Camera, Photometry, random_poses, render_view


def test_half_image_pixels_are_centred_between_full_pixels() -> None:
    """Half pixel (x, y) is the mean of full pixels 2x..2x+1: a ramp f = 2x + 2y reads
    f(2x + 0.5, 2y + 0.5) there; an odd last row and column are dropped."""
    y, x = np.mgrid[0:41, 0:61]
    full = (2 * x + 2 * y).astype(np.uint8)
    half = half_image(full)
    hy, hx = np.mgrid[0:20, 0:30]
    assert half.shape == (20, 30)
    np.testing.assert_array_equal(half, 2 * (2 * hx + 0.5) + 2 * (2 * hy + 0.5))


def test_1080p_detection_with_the_half_search_matches_the_full_search() -> None:
    """Markers with modules of several pixels at half resolution: the half search alone finds
    every marker the full search finds, and the full-resolution edge fit puts their corners
    within 0.01 px of the full search's, as close to the truth."""
    board = Board(cols=8, rows=5)
    cam = Camera.preset("hd")
    rvec, tvec = random_poses(board, cam, 1, np.random.default_rng(0), partial_fraction=0.0)[0]
    view = render_view(board, cam, rvec, tvec, photometry=Photometry.clean(),
                       rng=np.random.default_rng(7))
    half_det = Detector(board, DetectorConfig(half_search_above_px=1000))
    half = half_det.detect(view.image)
    full = Detector(board, DetectorConfig(half_search_above_px=0)).detect(view.image)
    assert half_det._candidates is not None and not half_det._candidates.full_searched
    assert len(full) == board.n_markers
    np.testing.assert_array_equal(half.ids, full.ids)
    assert np.abs(half.corners_px - full.corners_px).max() < 0.01

    def rms(corners: np.ndarray) -> float:
        true = view.corners_px[np.searchsorted(view.ids, full.ids)]
        return float(np.sqrt(np.mean(np.sum((corners - true) ** 2, axis=2))))

    assert rms(half.corners_px) < 1.05 * rms(full.corners_px) + 1e-3
    assert rms(half.corners_px) < 0.02
