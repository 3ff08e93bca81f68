"""How far a lens's bends are trusted, against sides whose true bends are known.

The sides' free parabolas scatter about the true bend by their own sigma; the lens bends
the inner sides exactly and misses the curvature of the outer ones by a known amount.
"""

from __future__ import annotations

import numpy as np

from artcal_ros.core.detect.bends import band_misfit, trusted_bends
from artcal_ros.core.detect.lens import BEND_BANDS, DivisionLens, LensPool
from artcal_ros.core.detect.sides import SideModel
from artcal_ros.synth import Camera

SHAPE = (800, 1280)
HALF = 0.5 * float(np.hypot(1280, 800))
CENTRE = np.array([639.5, 399.5])
LENS = DivisionLens(-0.3, CENTRE, HALF)


def _sides(rng: np.random.Generator, n: int, radius: tuple[float, float]
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n sides (start (n, 2), direction (n, 2), length (n,)) with midpoints at radii in
    ``radius`` (half diagonals)."""
    r = rng.uniform(*radius, n) * HALF
    phi = rng.uniform(0, 2 * np.pi, n)
    mid = CENTRE + np.c_[r * np.cos(phi), r * np.sin(phi)]
    ang = rng.uniform(0, 2 * np.pi, n)
    u = np.c_[np.cos(ang), np.sin(ang)]
    length = rng.uniform(25.0, 120.0, n)
    return mid - 0.5 * length[:, None] * u, u, length


def _frame(rng: np.random.Generator, miss_curvature: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, SideModel, np.ndarray]:
    """300 inner sides (radius < 0.5) and 40 outer ones (0.92 - 0.99); the lens's bend
    misses the outer sides' curvature by ``miss_curvature`` px^-1 (either sign)."""
    inner, outer = _sides(rng, 300, (0.05, 0.48)), _sides(rng, 40, (0.92, 0.99))
    a, u, length = (np.concatenate([x, y]) for x, y in zip(inner, outer, strict=True))
    S = len(length)
    true = rng.normal(0.0, 0.2, S)
    miss = np.r_[np.zeros(300), rng.choice([-1.0, 1.0], 40) * miss_curvature]
    lens_bend = true + miss * length**2 / 8.0
    sd = rng.uniform(0.02, 0.06, S)
    free = SideModel(length, np.full(S, 3))
    free.coef[:, 2] = true + rng.normal(0.0, 1.0, S) * sd
    free.cov[:, 2, 2] = sd**2 - 0.01**2      # (the floor is added back)
    free.count[:] = 40
    return a, u, length, lens_bend, free, true


def test_a_lens_that_fits_everywhere_is_trusted_everywhere() -> None:
    rng = np.random.default_rng(1)
    a, u, length, bend, free, _ = _frame(rng, 0.0)
    lens, held, var = trusted_bends(bend, LENS, a, u, length, SHAPE, free, None)
    assert isinstance(lens, DivisionLens)
    assert max(lens.bend_misfit) == 0.0
    np.testing.assert_array_equal(held, bend)
    assert not var.any()


def test_the_missed_curvature_is_found_and_the_outer_bends_follow_the_sides() -> None:
    rng = np.random.default_rng(2)
    miss = 4e-4    # px^-1: 0.125 px of bend on a 50 px side, 0.72 px on a 120 px one
    pool = LensPool()
    for _ in range(3):     # pooled over frames, as a Detector's sides are
        a, u, length, bend, free, true = _frame(rng, miss)
        lens, held, var = trusted_bends(bend, LENS, a, u, length, SHAPE, free, pool)
    assert isinstance(lens, DivisionLens)
    misfit, f0 = band_misfit(pool.bend_evidence)
    assert 0.8 < f0 < 1.25                      # the inner sides scatter by their sigmas
    outer = BEND_BANDS.index(0.9)
    assert not misfit[:outer].any()             # no misfit where the lens fits
    assert 0.5 * miss < np.sqrt(misfit[outer]) < 1.5 * miss
    inner = slice(0, 300)
    np.testing.assert_array_equal(held[inner], bend[inner])
    assert not var[inner].any()
    out = slice(300, None)
    err_lens, err_held = bend[out] - true[out], held[out] - true[out]
    assert np.sqrt(np.mean(err_held**2)) < 0.5 * np.sqrt(np.mean(err_lens**2))
    # the held bends' sigmas say how far off they are (not the lens's error)
    z = err_held / np.sqrt(var[out])
    assert 0.6 < np.sqrt(np.mean(z**2)) < 1.6


def test_a_known_camera_is_trusted() -> None:
    rng = np.random.default_rng(3)
    a, u, length, bend, free, _ = _frame(rng, 4e-4)
    cam = Camera.preset("wide")
    lens, held, var = trusted_bends(bend, cam, a, u, length, SHAPE, free, None)
    assert lens is cam
    np.testing.assert_array_equal(held, bend)
    assert not var.any()


def test_sides_without_a_parabola_take_the_lens_misfit_as_their_variance() -> None:
    rng = np.random.default_rng(4)
    a, u, length, bend, free, _ = _frame(rng, 4e-4)
    lens, _, _ = trusted_bends(bend, LENS, a, u, length, SHAPE, free, None)
    assert isinstance(lens, DivisionLens)
    _, held, var = trusted_bends(bend, lens, a, u, length, SHAPE, None, None)
    np.testing.assert_array_equal(held, bend)
    radius = np.linalg.norm(a + 0.5 * length[:, None] * u - CENTRE, axis=1) / HALF
    band = np.searchsorted(BEND_BANDS, radius, side="right") - 1
    expected = np.asarray(lens.bend_misfit)[band] * (length**2 / 8) ** 2
    np.testing.assert_allclose(var, expected)
    assert expected[300:].all() and not expected[:300].any()


def test_a_few_sides_judge_nothing() -> None:
    """One small frame (100 sides inside half the diagonal, their parabolas scattering at
    half their sigmas) leaves the lens trusted: its scatter is no reference yet."""
    rng = np.random.default_rng(5)
    a, u, length, bend, free, true = _frame(rng, 4e-4)
    keep = np.r_[np.arange(100), np.arange(300, 340)]
    free = SideModel(length[keep], free.order[keep])
    # the outer parabolas show the lens's miss (true, not the lens's bend)
    free.coef[:, 2] = true[keep] + rng.normal(0.0, 0.5, len(keep)) * 0.04
    free.cov[:, 2, 2] = 0.04**2
    free.count[:] = 40
    lens, held, var = trusted_bends(bend[keep], LENS, a[keep], u[keep], length[keep], SHAPE,
                                    free, None)
    assert isinstance(lens, DivisionLens)
    assert max(lens.bend_misfit) == 0.0
    np.testing.assert_array_equal(held, bend[keep])
    assert not var.any()
