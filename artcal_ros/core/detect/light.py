"""The light's slope along each marker side, from the frame's smooth light field.

The blurred-step model (:mod:`~artcal_ros.core.detect.step_model`) holds a side's levels
constant along the side. Where the light changes along it (a light gradient across the
board, vignetting), the fit tilts the edge towards the dark where the light is stronger:
about 1.4 px of offset between the side's ends per unit of relative light change under a
blur of a pixel, enough to move corners by a few hundredths of a pixel. Every side's fitted
contrast samples the light at its middle; a low-order polynomial of their logarithm over
the image is the frame's light field, smooth and measured by all sides together. Its
slope along a side scales that side's samples back to the light at its middle, and the
side is fitted again.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

# sides whose light changes by less than this share from their middle to an end keep
# their first fit (the tilt it leaves is below ~0.003 px)
_LIGHT_MIN = 0.002
# sides needed for a plane (a quadric) of log light over the image
_PLANE_SIDES, _QUADRIC_SIDES = 8, 24


def _design(xy: np.ndarray, quadric: bool) -> np.ndarray:
    x, y = xy[:, 0], xy[:, 1]
    cols = [np.ones_like(x), x, y] + ([x * x, x * y, y * y] if quadric else [])
    return np.stack(cols, axis=1)


def light_slopes(contrast: np.ndarray, start: np.ndarray, u: np.ndarray,
                 length: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """(S,) the light's relative change from each side's middle to its end (at tau = 1).

    Args:
        contrast: (S,) each side's fitted contrast (its sign is the border's polarity).
        start: (S, 2) where each side starts (tau = -1), pixels.
        u: (S, 2) unit direction of each side (tau grows along it).
        length: (S,) side lengths, pixels.
        ok: (S,) bool, sides whose fit is usable.

    Returns:
        zeros where too few sides are usable for a light field.
    """
    level = np.abs(np.asarray(contrast, dtype=np.float64))
    middle = start + 0.5 * length[:, None] * u
    use = np.asarray(ok, bool) & np.isfinite(level) & (level > 0)
    S = len(level)
    if use.sum() < _PLANE_SIDES:
        return np.zeros(S)
    quadric = bool(use.sum() >= _QUADRIC_SIDES)
    centre = middle[use].mean(axis=0)
    scale = max(float(np.abs(middle[use] - centre).max()), 1.0)
    xy = (middle - centre) / scale
    log_level = np.log(np.where(use, level, 1.0))
    keep = use.copy()
    coef = np.zeros(6 if quadric else 3)
    for _ in range(2):
        # a least-squares field, then again without the sides far off it (clipped or
        # misfitted sides)
        A = _design(xy[keep], quadric)
        coef = np.linalg.lstsq(A, log_level[keep], rcond=None)[0]
        res = log_level - _design(xy, quadric) @ coef
        mad = float(np.median(np.abs(res[keep])))
        keep = use & (np.abs(res) <= max(4.0 * 1.4826 * mad, 0.01))
        if keep.sum() < len(coef) + 2:
            return np.zeros(S)
    x, y = xy[:, 0], xy[:, 1]
    gx = coef[1] + (2 * coef[3] * x + coef[4] * y if quadric else 0.0)
    gy = coef[2] + (coef[4] * x + 2 * coef[5] * y if quadric else 0.0)
    slope = 0.5 * length / scale * (gx * u[:, 0] + gy * u[:, 1])
    return np.where(np.isfinite(slope), slope, 0.0)


def in_light(values: np.ndarray, tau: np.ndarray, side: np.ndarray, slope: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray]:
    """The samples' values scaled to the light at their side's middle, and (L,) int the sides
    whose light changes enough to be scaled (the values themselves where none does).

    Args:
        values: (N,) the samples' linear intensities; tau: (N,) their place along their
            side (-1 to 1); side: (N,) their side.
        slope: (S,) the light's change along each side (:func:`light_slopes`).
    """
    lit = np.flatnonzero(np.abs(slope) > _LIGHT_MIN)
    if len(lit) == 0:
        return values, lit
    kept = np.zeros(len(slope))
    kept[lit] = slope[lit]
    return values / (1.0 + kept[side] * tau), lit


def fit_in_light(fit: Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]],
                 values: np.ndarray, tau: np.ndarray, side: np.ndarray,
                 first: tuple[np.ndarray, np.ndarray, np.ndarray], contrast: np.ndarray,
                 start: np.ndarray, u: np.ndarray, length: np.ndarray, ok: np.ndarray,
                 **kw: object
                 ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
    """Sides fitted again where the light changes along them (module docstring).

    Args:
        fit: ``fit(values, coef0=, blur0=, sides=, contrast_out=, **kw)`` -> (coef, cov,
            blur) (:func:`~artcal_ros.core.detect.step_model.fit_step_model` with its
            samples bound).
        values: (N,) the samples' linear intensities; tau: (N,) their place along their
            side (-1 to 1); side: (N,) their side.
        first: the first fit's (coef, cov, blur) of every side; contrast: (S,) its
            contrasts (updated for the sides fitted again).
        start, u, length, ok: see :func:`light_slopes`.

    Returns:
        (coef, cov, blur) with the lit sides' rows replaced, the values scaled to the
        light at their side's middle (:func:`in_light`) and (S,) the light's slopes
        (:func:`light_slopes`; a later fit of the same sides may start in that light).
    """
    slope = light_slopes(contrast, start, u, length, ok)
    scaled, lit = in_light(values, tau, side, slope)
    if len(lit) == 0:
        return first, values, slope
    coef, cov, blur = (np.array(x) for x in first)
    again = fit(scaled, coef0=coef, blur0=blur, sides=lit, contrast_out=contrast, **kw)
    for whole, part in zip((coef, cov, blur), again, strict=True):
        whole[lit] = part[lit]
    return (coef, cov, blur), scaled, slope
