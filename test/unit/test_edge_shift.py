"""The edge shift read against the centres around each marker, against renderer truth."""

from __future__ import annotations

import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, DetectorConfig
from artcal_ros.core.detect.edge_shift import (
    compensate,
    neighbourhood_shift_px,
    robust_shift_px,
)
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
from artcal_ros.synth.poses import marker_truth

WEBCAM = Camera.preset("webcam")
# the webcam's intrinsics without its distortion: exact pinhole truth
PINHOLE = Camera("plumb_bob", WEBCAM.K, np.zeros(5), WEBCAM.size)


def _side_offsets(true_q: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(N, 4) distance of each corner of ``q`` from the two true sides through it, measured
    outward along their normals (corner i lies on sides i - 1 and i)."""
    nxt = np.roll(true_q, -1, axis=1)
    t = (nxt - true_q) / np.linalg.norm(nxt - true_q, axis=-1, keepdims=True)
    n = np.stack([t[..., 1], -t[..., 0]], axis=-1)
    n *= np.sign(np.sum((0.5 * (true_q + nxt) - true_q.mean(axis=1, keepdims=True)) * n,
                        axis=-1, keepdims=True))
    on_side = np.sum((q - true_q) * n, axis=-1)                  # corner i, side i
    on_prev = np.sum((q - true_q) * np.roll(n, 1, axis=1), axis=-1)  # corner i, side i - 1
    return np.concatenate([on_side, on_prev], axis=1)


@pytest.mark.parametrize("shift_px", [-0.25, 0.08])
def test_neighbourhood_shift_recovers_a_known_shift(shift_px: float) -> None:
    """Every true quad grown by ``shift_px`` along its sides' normals is read back to 2 mpx;
    the centres (which a shift does not move) are the truth's."""
    board = Board()
    rng = np.random.default_rng(4301)
    for rvec, tvec in random_poses(board, PINHOLE, 3, rng):
        corners, centers, inside, _ = marker_truth(board, PINHOLE, rvec, tvec)
        ids = board.ids[inside]
        q, c = corners[inside], centers[inside]
        grown = compensate(q, -shift_px)
        assert np.allclose(compensate(grown, shift_px), q, atol=1e-9)
        # the grown quad's sides lie shift_px outside the true sides, each along its normal
        normal_gap = _side_offsets(q, grown)
        assert np.allclose(normal_gap, shift_px, atol=1e-9)
        d = neighbourhood_shift_px(ids, grown, c, board)
        assert np.isfinite(d).sum() >= 8
        assert robust_shift_px(d)[0] == pytest.approx(shift_px, abs=0.002)
        # unshifted truth reads as no shift
        assert np.nanmax(np.abs(neighbourhood_shift_px(ids, q, c, board))) < 0.002


def test_marker_without_neighbourhood_has_no_shift() -> None:
    board = Board()
    rng = np.random.default_rng(4302)
    rvec, tvec = random_poses(board, PINHOLE, 1, rng, partial_fraction=0.0)[0]
    corners, centers, _, _ = marker_truth(board, PINHOLE, rvec, tvec)
    # ids 0 and 40 share no 3 x 3 block: fewer than 5 centres each
    pick = np.array([0, 40])
    d = neighbourhood_shift_px(board.ids[pick], corners[pick], centers[pick], board)
    assert np.isnan(d).all()
    assert robust_shift_px(d)[1] == float("inf")


@pytest.mark.parametrize("polarity", ["black", "mixed"])
def test_compensation_does_not_hurt_defocused_corners(polarity: str) -> None:
    """Defocus moves no edge: the removed shift must not add error (it did, 0.0335 against
    0.0277 px, when the shift was read from each marker's own corners)."""
    board = Board(polarity=polarity)
    rng = np.random.default_rng(4303)
    views = [render_view(board, WEBCAM, r, t, photometry=Photometry(defocus_px=1.4), rng=rng)
             for r, t in random_poses(board, WEBCAM, 2, rng, partial_fraction=0.5)]
    rms = {}
    for on in (False, True):
        det = Detector(board, DetectorConfig(edge_shift=on))
        errs = []
        for v in views:
            d = det.detect(v.image)
            k = d.ids - board.first_id
            good = v.inside[k] & (v.side_px[k] >= 20)
            errs.append(np.linalg.norm(d.corners_px - v.corners_px[k], axis=2)[good].ravel())
            if on:
                assert abs(d.edge_shift_px) < 0.02
        e = np.concatenate(errs)
        assert len(e) > 40
        rms[on] = float(np.sqrt(np.mean(e ** 2)))
    assert rms[True] <= rms[False] + 0.001, rms
