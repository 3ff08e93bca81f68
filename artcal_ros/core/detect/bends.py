"""How much of a side's bend to believe: its own fitted parabola, or the lens's bend.

A side fitted with a free parabola keeps it only where the curvature is significant
(:func:`drop_flat_parabolas`).

With a lens every side is bent as the lens bends a straight edge (``lens_bend`` of
:mod:`.plumb`) and only its offset and angle are fitted. An estimated division lens only
approximates the real one: far out in a strong lens (the image corners of a wide-angle
lens) it can bend a side by tenths of a pixel more or less than the lens does, and the
corner moves by two thirds of that, far beyond its sigma from the fit. The sides' own
free parabolas, fitted before the lens was known, show where: per band of distance from
the centre (:data:`~.lens.BEND_BANDS`) their curvature's scatter about the lens's bend
beyond what the inner band's scatter explains is the curvature the lens misses there
(pooled over a stream's frames in :class:`~.lens.LensPool`). :func:`trusted_bends` then
holds each side at the lens's bend and its own parabola weighted by the two variances,
and gives the held bend that variance, which the corner's sigma carries.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from artcal_ros.core.detect.lens import BEND_BANDS, DivisionLens, Lens, LensPool
from artcal_ros.core.detect.sides import SideModel

__all__ = ["band_misfit", "drop_flat_parabolas", "trusted_bends"]

# a free parabola's curvature is trusted to no better than this, px (as plumb's floor)
_OBS_FLOOR_PX = 0.01
# sides of the inner band (radius below BEND_BANDS[1]) needed before any band is judged:
# they say how far the free parabolas scatter where the lens fits
_MIN_REFERENCE = 200
# sides a band needs before its own misfit counts (fewer: the band inward's)
_MIN_SIDES = 5
# a band's misfit counts beyond this many standard errors, and is shrunk by as many
_SIGNIFICANCE = 2.0
# a side's squared residual counts at most this many variances (one wild parabola)
_Z2_CAP = 400.0
# a side's parabola beyond this many sigmas of the lens's bend is not mixed in
_GUARD_SIGMAS = 4.0


def drop_flat_parabolas(model: SideModel) -> None:
    """Keep a parabola only where its curvature is significant (3 sigma); updates ``model``."""
    curved = model.order >= 3
    if not curved.any():
        return
    sd = np.sqrt(np.maximum(model.cov[:, 2, 2], 1e-30))
    keep = curved & (np.abs(model.coef[:, 2]) > 3.0 * sd)
    if (curved & ~keep).any():
        model.order = np.where(keep, 3, 2)
        model.coef[~keep, 2] = 0.0
        model.cov[~keep, 2, :] = 0.0
        model.cov[~keep, :, 2] = 0.0


def band_misfit(evidence: np.ndarray) -> tuple[np.ndarray, float]:
    """Curvature the lens misses per band, and the free parabolas' variance scale.

    Args:
        evidence: (5, B) per band: sides, their summed squared residuals in variances
            (z^2), and the sums z^2 / u, 1 / u, 1 / u^2 with u a side's curvature variance,
            px^-2 (see :func:`trusted_bends`).

    Returns:
        misfit (B,) px^-2, the variance of a straight edge's curvature the lens misses,
        never less than the band inward's; and f0, the inner band's mean z^2 (how far its
        parabolas' variances understate their scatter, at least 1: where they scatter less
        the excess is judged against their own variances; NaN, and no misfit, until it has
        ``_MIN_REFERENCE`` sides).
    """
    n, z2, a, b, c = evidence
    if n[0] < _MIN_REFERENCE:
        return np.zeros(len(n)), float("nan")
    f0 = max(float(z2[0] / n[0]), 1.0)
    c = np.maximum(c, 1e-300)
    # moment estimate weighted by 1 / u^2: sum (q^2 - f0 u) / u^2 / sum 1 / u^2, with
    # q^2 = z^2 u the squared curvature residual; its standard error where the lens fits
    tau2 = (a - f0 * b) / c
    se = f0 * np.sqrt(2.0 / c)
    judged = (n >= _MIN_SIDES) & (tau2 > _SIGNIFICANCE * se)
    out = np.where(judged, tau2 - _SIGNIFICANCE * se, 0.0)
    out[0] = 0.0
    return np.maximum.accumulate(out), f0


def trusted_bends(bend: np.ndarray, lens: Lens, a: np.ndarray, u: np.ndarray,
                  length: np.ndarray, shape: tuple[int, ...], free: SideModel | None,
                  pool: LensPool | None) -> tuple[Lens, np.ndarray, np.ndarray]:
    """The bend each side is held at and its variance, and the lens with its misfit.

    Args:
        bend: (S,) the lens's bend of each side (its parabola term), pixels.
        lens: the lens the sides are bent by. A known camera is trusted (variance 0).
        a, u: (S, 2) each side's start, pixels, and unit direction.
        length: (S,) side lengths, pixels.
        shape: the image's (height, width, ...).
        free: the sides' free parabolas fitted before the lens (None: there are none; the
            lens's ``bend_misfit`` is used as it is).
        pool: the stream's lens evidence; this frame's sides join it (None: the frame's
            sides alone say what the lens misses).

    Returns:
        the lens (a division lens carrying the misfit its bends were judged by), the
        bends (S,) pixels and their variances (S,) pixels^2.
    """
    if not isinstance(lens, DivisionLens):
        return lens, bend, np.zeros(len(bend))
    h, w = shape[:2]
    mid = a + 0.5 * length[:, None] * u
    radius = (np.hypot(mid[:, 0] - (w - 1) / 2.0, mid[:, 1] - (h - 1) / 2.0)
              / (0.5 * np.hypot(w, h)))
    band = np.searchsorted(np.asarray(BEND_BANDS), radius, side="right") - 1
    # a bend is the sag of the side's curvature: bend = curvature L^2 / 8
    sag2 = (length**2 / 8.0) ** 2
    f0 = float("nan")
    if free is not None:
        obs = free.coef[:, 2]
        var_obs = np.maximum(free.cov[:, 2, 2], 0.0) + _OBS_FLOOR_PX**2
        res = obs - bend
        use = (free.order >= 3) & (free.count >= 6) & np.isfinite(res) & np.isfinite(var_obs)
        z2 = np.minimum(res[use] ** 2 / var_obs[use], _Z2_CAP)
        curv_var = var_obs[use] / sag2[use]
        frame: np.ndarray = np.zeros((5, len(BEND_BANDS)))
        for row, v in enumerate((np.ones(len(z2)), z2, z2 / curv_var, 1.0 / curv_var,
                                 curv_var**-2.0)):
            np.add.at(frame[row], band[use], v)
        if pool is not None:
            pool.bend_evidence = pool.bend_evidence + frame
            frame = pool.bend_evidence
        misfit, f0 = band_misfit(frame)
        lens = replace(lens, bend_misfit=tuple(float(m) for m in misfit))
    if not lens.bend_misfit:
        return lens, bend, np.zeros(len(bend))
    var = np.asarray(lens.bend_misfit)[band] * sag2
    if free is not None and np.isfinite(f0):
        # the side's own parabola mixed in where the lens may be wrong and the two agree
        # within their variances
        s2 = f0 * var_obs
        mix = use & (var > 0) & (res**2 < _GUARD_SIGMAS**2 * (var + s2))
        w_lens = 1.0 / np.where(mix, var, 1.0)
        bend = np.where(mix, (bend * w_lens + obs / s2) / (w_lens + 1.0 / s2), bend)
        var = np.where(mix, 1.0 / (w_lens + 1.0 / s2), var)
    return lens, bend, var
