"""The division lens estimated from the image, against the renderer's exact truth.

A 170-degree equidistant lens needs a division model near the edge of what it can follow
(r^2 coefficient about -1.1, a fold just outside the 90-degree circle): mapping back must
stay on the model's one-to-one branch, and the estimate pooled over frames must keep
following the lens as evidence grows.
"""

from __future__ import annotations

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector
from artcal_ros.core.detect.centers import diagonal_centers
from artcal_ros.core.detect.lens import DivisionLens
from artcal_ros.synth import Camera, Photometry, random_poses, render_view

# the equidistant series theta cot(theta) with theta = 1.83 r: the division model of an
# f = 350 px fisheye with the 640 px half diagonal of a 1024 x 768 image as unit radius
FISHEYE_DIVISION = DivisionLens(-1.1146, np.array([511.5, 383.5]), 640.0, -0.2484, -0.0791)


def test_division_distort_stays_on_the_one_to_one_branch() -> None:
    lens = FISHEYE_DIVISION
    fold = lens.fold_radius()
    assert 0.8 < fold < 0.9  # theta = 90 degrees is r = 0.86
    rng = np.random.default_rng(11)
    r = rng.uniform(0.0, 0.995 * fold, 3000) * lens.scale
    a = rng.uniform(0.0, 2 * np.pi, 3000)
    pts = lens.center + np.c_[r * np.cos(a), r * np.sin(a)]
    assert lens.one_to_one(pts).all()
    back = lens.distort(lens.undistort(pts))
    assert np.abs(back - pts).max() < 1e-6
    # a straightened point beyond everything the branch reaches maps to the fold, not
    # to another root of the polynomial
    far = lens.center + np.array([[1e4 * lens.scale, 0.0]])
    r_far = np.linalg.norm(lens.distort(far) - lens.center) / lens.scale
    assert fold - 0.01 < r_far <= fold
    assert not lens.one_to_one(lens.center + np.array([[1.01 * fold * lens.scale, 0.0]]))[0]


def test_centres_beyond_the_fold_keep_their_plain_diagonals() -> None:
    # a square far out, beyond the fold: the lens cannot map it, its diagonals can
    square = FISHEYE_DIVISION.center + np.array([[[600.0, 0.0], [610.0, 0.0],
                                                  [610.0, 10.0], [600.0, 10.0]]])
    centres, _ = diagonal_centers(square, np.full((1, 4), 0.02), FISHEYE_DIVISION)
    np.testing.assert_allclose(centres[0], square[0].mean(axis=0), atol=1e-9)


def test_pooled_fisheye_lens_keeps_centres_on_truth() -> None:
    """Seven clean frames of a half-size 170-degree fisheye through one Detector: every
    frame's centres and corners stay close to the truth as the pool grows (the pooled
    estimate went past lam = -1, was rejected as implausible, and the centres of those
    frames were 0.3 - 0.7 px off)."""
    board = Board(cols=7, rows=5)
    fisheye = Camera.preset("fisheye")
    cam = Camera("equidistant", np.array([[175.0, 0.0, 257.0], [0.0, 175.2, 190.8],
                                          [0.0, 0.0, 1.0]]), fisheye.dist, (512, 384))
    rng = np.random.default_rng(5)
    detector = Detector(board)
    for rvec, tvec in random_poses(board, cam, 7, rng, partial_fraction=0.0):
        view = render_view(board, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
        det = detector.detect(view.image)
        k = det.ids - board.first_id
        assert len(k) >= 30
        centre = np.linalg.norm(det.centers_px - view.centers_px[k], axis=1)
        corner = np.linalg.norm(det.corners_px - view.corners_px[k], axis=2)
        assert np.sqrt(np.mean(centre**2)) < 0.06 and centre.max() < 0.1
        assert np.sqrt(np.mean(corner**2)) < 0.05


def test_plausible_division_lenses() -> None:
    from artcal_ros.core.detect.plumb import _plausible

    centre, scale = FISHEYE_DIVISION.center, FISHEYE_DIVISION.scale
    use = np.ones(100, bool)
    inside = np.linspace(0.1, 0.8, 100)  # sides within the fisheye model's fold (0.86)
    fisheye = np.array([-1.1146, -0.2484, -0.0791])
    lens = _plausible(fisheye, centre, scale, 0.01, use, inside)
    assert lens is not None and abs(lens.significance - 111.46) < 0.01
    # a few sides beyond the fold (a close view's outermost) are tolerated, many are not
    some_out = inside.copy()
    some_out[:5] = 0.9
    assert _plausible(fisheye, centre, scale, 0.01, use, some_out) is not None
    many_out = inside.copy()
    many_out[:20] = 0.9
    assert _plausible(fisheye, centre, scale, 0.01, use, many_out) is None
    # the strong pincushion a noisy dark frame of a barrel lens fits is no lens
    assert _plausible(np.array([1.15, -0.855, -0.014]), centre, scale, 0.1, use,
                      inside) is None
    assert _plausible(np.array([np.nan, 0.0, 0.0]), centre, scale, 0.1, use, inside) is None


def test_lens_pool_restore_withdraws_a_frames_evidence() -> None:
    """A frame pooled after a snapshot and then withdrawn by restore leaves the pool as the
    snapshot found it: fitting that frame again gives the very same lens."""
    from artcal_ros.core.detect.edges import refine_quads
    from artcal_ros.core.detect.lens import LensPool

    board = Board()
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(3)
    pool = LensPool()

    def pooled_lens(rvec: np.ndarray, tvec: np.ndarray) -> tuple[float, float, float]:
        view = render_view(board, cam, rvec, tvec, photometry=Photometry.exact(), rng=rng)
        quads = view.corners_px[view.inside]
        fit = refine_quads(view.image / 255.0, quads, np.ones(len(quads), bool), board.bits,
                           curve_min_px=20.0, lens_pool=pool)
        assert isinstance(fit.lens, DivisionLens)
        return fit.lens.lam, fit.lens.lam2, fit.lens.lam3

    first, second = random_poses(board, cam, 2, rng, partial_fraction=0.0)
    pooled_lens(*first)
    state = pool.snapshot()
    info, bends = pool.info.copy(), pool.bend_evidence.copy()
    lens = pooled_lens(*second)
    assert not np.array_equal(pool.info, info)          # the second frame joined the pool
    assert not np.array_equal(pool.bend_evidence, bends)
    np.testing.assert_array_equal(state.info, info)     # and the snapshot kept its moment
    pool.restore(state)
    np.testing.assert_array_equal(pool.info, info)
    np.testing.assert_array_equal(pool.bend_evidence, bends)
    assert pooled_lens(*second) == lens
