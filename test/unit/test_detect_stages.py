"""The detection stages on their own, against the renderer's exact truth (fixed seeds).

:func:`refine_quads` must pull quads perturbed by ~0.6 px RMS back onto the true
corners, and :func:`decode_quads` must read the true ids from the true quads and
nothing from a blank or cluttered image. The whole pipeline is in test_detect.py.
"""

from __future__ import annotations

import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.detect.decode import PatternTable, decode_quads
from artcal_ros.core.detect.edges import refine_quads
from artcal_ros.core.detect.image import linearise, to_gray
from artcal_ros.core.detect.lens import DivisionLens
from artcal_ros.core.detect.patterns import inner_border_cells
from artcal_ros.core.detect.sampling import bilinear, bilinear_at, border_is_dark
from artcal_ros.core.homography import apply_h, apply_one, homographies
from artcal_ros.synth import Camera, Photometry, RenderedView, random_poses, render_view

CAM = Camera.preset("webcam")  # strong barrel distortion: bent sides near the image corners
BOARD = Board()


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.fixture(scope="module")
def scene() -> tuple[RenderedView, np.ndarray, np.ndarray]:
    """A clean view, its linear image, and which markers are whole and >= 20 px."""
    rng = np.random.default_rng(1234)
    rvec, tvec = random_poses(BOARD, CAM, 1, rng, partial_fraction=0.0)[0]
    view = render_view(BOARD, CAM, rvec, tvec, photometry=Photometry.clean(), rng=rng)
    lin = linearise(to_gray(view.image), 2.2)
    use = view.inside & (view.side_px >= 20)
    assert use.sum() >= 20
    return view, lin, use


@pytest.fixture(scope="module")
def clutter() -> np.ndarray:
    """Linear image of the cluttered background alone (the board is behind the camera)."""
    rng = np.random.default_rng(99)
    view = render_view(BOARD, CAM, rng.normal(0, 0.3, 3), np.array([0.0, 0.0, -2.0]), rng=rng)
    return linearise(to_gray(view.image), 2.2)


def test_bilinear_is_exact_on_a_plane_and_clamps_at_the_border() -> None:
    h, w = 7, 9
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float64)
    image = 0.3 * xx - 0.7 * yy + 2.0
    rng = np.random.default_rng(5)
    x = rng.uniform(0.0, w - 1.0, (4, 50))
    y = rng.uniform(0.0, h - 1.0, (4, 50))
    out = bilinear(image, x, y)
    assert out.shape == x.shape
    np.testing.assert_allclose(out, 0.3 * x - 0.7 * y + 2.0, atol=1e-5)
    # pixel centers give the pixels themselves; outside the image, the nearest border pixel
    np.testing.assert_allclose(bilinear(image, np.array([3.0]), np.array([2.0])), image[2, 3])
    far = bilinear(image, np.array([-5.0, 50.0]), np.array([-5.0, 50.0]))
    np.testing.assert_allclose(far, [image[0, 0], image[-1, -1]], atol=1e-5)
    # the one-point sampler the compiled kernels call is the same sampler
    assert [bilinear_at(image, float(a), float(b)) for a, b in zip(x[0], y[0], strict=True)] \
        == out[0].tolist()


def test_one_homography_map_for_arrays_and_single_points() -> None:
    square = np.array([[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]])
    quad = np.array([[[10.0, 20.0], [52.0, 18.0], [61.0, 70.0], [8.0, 55.0]]])
    H = homographies(square, quad)
    np.testing.assert_allclose(apply_h(H, square), quad, atol=1e-9)
    # the diagonals' crossing maps to the quad's diagonals' crossing (a projective invariant)
    p, q = quad[0, 0], quad[0, 2]
    r, s = quad[0, 1], quad[0, 3]
    t = np.linalg.solve(np.column_stack([q - p, r - s]), r - p)[0]
    np.testing.assert_allclose(apply_one(H[0], 0.5, 0.5), p + t * (q - p), atol=1e-9)
    assert apply_one(H[0], 0.3, 0.8) == tuple(apply_h(H, np.array([[[0.3, 0.8]]]))[0, 0])


@pytest.mark.parametrize("setup", ["lines", "given_lens", "estimated_lens"])
def test_refine_quads_recovers_perturbed_corners(scene, setup: str) -> None:
    view, lin, use = scene
    truth, ids = view.corners_px[use], view.ids[use]
    rng = np.random.default_rng(7)
    start = truth + rng.uniform(-0.75, 0.75, truth.shape)
    assert _rms(np.linalg.norm(start - truth, axis=2)) > 0.4  # the test has something to do
    dark = border_is_dark(lin, truth, BOARD.bits)
    assert dark.all()  # black markers on white
    lens = CAM if setup == "given_lens" else None
    fit = refine_quads(lin, start, dark, BOARD.bits, passes=1, lens=lens,
                       allow_curvature=setup == "estimated_lens", curve_min_px=20.0,
                       inner_same=inner_border_cells(BOARD, ids, rows=1))
    assert fit.ok.all()
    err = np.linalg.norm(fit.corners_px - truth, axis=2)
    assert _rms(err) < 0.05, setup
    assert err.max() < 0.12, setup
    sigma = fit.corner_sigma_px
    assert np.isfinite(sigma).all() and (sigma > 0).all() and np.median(sigma) < 0.1
    if setup == "given_lens":
        assert fit.lens is lens
    elif setup == "estimated_lens":
        # plumb lines: the webcam's barrel distortion is a negative division term
        assert isinstance(fit.lens, DivisionLens) and fit.lens.lam < -0.05
    else:
        assert fit.lens is None


def test_probe_subset_refits_its_sides_as_the_whole_fit_does(scene) -> None:
    """A tone probe's re-fit of a few sides on their own samples (two copies) gives what
    the same fit of those sides among all of the frame's samples gives."""
    from artcal_ros.core.detect.edges import ProbeFit
    from artcal_ros.core.detect.step_model import fit_step_model

    view, lin, use = scene
    fits: list[ProbeFit] = []
    refine_quads(lin, view.corners_px[use], np.ones(use.sum(), bool), BOARD.bits, passes=1,
                 inner_same=inner_border_cells(BOARD, view.ids[use], rows=1),
                 tone_probe=fits.append)
    fit = fits[-1]
    sides = fit.sides[:5]
    whole = fit_step_model(fit.values, fit.samples, fit.coef, blur0=fit.blur, sides=sides,
                           iterations=2)[0][sides]
    fit_values, values = fit.subset(sides, copies=2)
    assert len(values) == np.isin(fit.samples.side, sides).sum()
    cost = np.zeros(10)
    fit_values(np.concatenate([values, values]), coef0=np.tile(fit.coef[sides], (2, 1)),
               blur0=np.tile(fit.blur[sides], 2), cost_out=cost)
    assert (cost > 0).all()   # every copy of every side was fitted
    sub, _ = fit.samples.subset(sides, copies=2)
    again = fit_step_model(np.concatenate([values, values]), sub,
                           np.tile(fit.coef[sides], (2, 1)), blur0=np.tile(fit.blur[sides], 2),
                           iterations=2)[0]
    np.testing.assert_array_equal(again[:5], whole)
    np.testing.assert_array_equal(again[5:], whole)


def test_refine_quads_under_a_light_gradient_as_under_even_light() -> None:
    """Light falling off across the board (30 % from its centre to a corner) changes each
    side's levels along it; fitted as constant, they tilt the edges towards the dark (the
    corners of 55 px markers ~0.009 px from the truth against 0.003 px under even light).
    The frame's light field takes the change out. Exact renders: no noise."""
    board = Board(cols=10, rows=8, marker_length=0.0225, marker_separation=0.0075)
    cam = Camera.preset("hd")
    rvec, tvec = random_poses(board, cam, 1, np.random.default_rng(4321),
                              partial_fraction=0.0)[0]
    errors = {}
    for gradient in (0.0, 0.3):
        light = Photometry.clean().with_(gradient=gradient, vignetting=0.0, noise=False)
        view = render_view(board, cam, rvec, tvec, photometry=light,
                           rng=np.random.default_rng(7))
        use = view.inside
        fit = refine_quads(linearise(to_gray(view.image), 2.2), view.corners_px[use],
                           np.ones(use.sum(), bool), board.bits, passes=1,
                           inner_same=inner_border_cells(board, view.ids[use], rows=1))
        errors[gradient] = _rms(fit.corners_px - view.corners_px[use])
    assert errors[0.0] < 0.005
    assert errors[0.3] < 1.3 * errors[0.0] + 0.002


def test_refine_quads_of_nothing() -> None:
    fit = refine_quads(np.zeros((20, 20), np.float32), np.zeros((0, 4, 2)),
                       np.zeros(0, bool), BOARD.bits)
    assert fit.corners_px.shape == (0, 4, 2) and fit.corner_sigma_px.shape == (0, 4)
    assert fit.ok.shape == (0,)


def test_decode_quads_reads_the_true_ids_in_any_corner_order(scene) -> None:
    view, lin, use = scene
    truth, ids = view.corners_px[use], view.ids[use]
    table = PatternTable(BOARD, any_polarity=False)
    # as the quad finder may hand them over: any start corner, either direction
    k = np.arange(len(truth))
    shuffled = np.stack([np.roll(q, int(s), axis=0) for q, s in zip(truth, k % 4, strict=True)])
    shuffled[k % 2 == 1] = shuffled[k % 2 == 1][:, ::-1]
    quads, got, index, errors = decode_quads(lin, shuffled, table, grow_px=0.0)
    assert len(got) == len(ids)
    np.testing.assert_array_equal(index, k)
    np.testing.assert_array_equal(got, ids)
    assert (errors <= 2).all()
    # returned in the board's corner order (TL, TR, BR, BL), unchanged when grow_px = 0
    np.testing.assert_allclose(quads, truth, atol=1e-9)


def test_decode_quads_reads_nothing_on_blank_or_cluttered_images(scene, clutter) -> None:
    view, _, use = scene
    truth = view.corners_px[use]
    table = PatternTable(BOARD, any_polarity=True)
    blank = np.full(clutter.shape, 0.5, np.float32)
    for image in (blank, clutter):
        for grow in (0.0, 0.7):
            _, got, index, _ = decode_quads(image, truth, table, grow_px=grow)
            assert len(got) == 0 and len(index) == 0
    quads, got, index, errors = decode_quads(clutter, np.zeros((0, 4, 2)), table)
    assert quads.shape == (0, 4, 2) and len(got) == len(index) == len(errors) == 0
