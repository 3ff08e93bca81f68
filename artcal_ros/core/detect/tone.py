"""The camera's tone curve: encoded grey values <-> linear light, estimated from the edges.

Every sub-pixel measurement is made in linear light (a pixel integrates light;
the encoding comes afterwards), so the detector must know the curve. It is
estimated, not assumed: a blurred step is the pixel footprint convolved with
the blur in *linear* light, so read through the wrong curve its profile is
asymmetric (the dark and the light half of the transition disagree) and the
step model fits it worse. The pilot sides of a frame's edge fit are re-fitted
through a grid of candidate curves (power laws ``linear = v ** gamma`` from 1
to 2.8, and the sRGB curve); each candidate's residual, relative to each side's
contrast, is summed over the sides whose step every re-fit still sees
(:func:`sound_sides`), pooled over the frames of one camera in units of each
frame's own residual level (:class:`TonePool`), and the best fit is the minimum of
a parabola through the pooled costs.

The curve the detector then *uses* is the common gamma 2.2 unless the evidence
against it is strong: its cost more than :data:`SWITCH_COST` above the best
candidate's, more than :data:`SWITCH_SIGMAS` sigma from the best fit, and (for a
power law) more than :data:`SWITCH_GAMMA` above it or :data:`SWITCH_GAMMA_BELOW`
below it in gamma. Measured on renders with exact truth, the best fit reads
0.1-0.15 high on clean frames, up to 0.35 low under strong noise (the noise in
linear light grows with the gamma it is read through) and up to 0.75 low on single
dim, defocused JPEG frames (JPEG drops fine detail after the encoding: a blur in
encoded values, which looks like a flatter curve); so a best fit within 0.4 above
or 0.85 below 2.2 is no evidence of another curve. A linear camera (read as 2.2 its
corners are off by 0.3 px; its best fit stays below 1.2 on those frames too) clears
every threshold from one frame.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import cv2
import numpy as np

__all__ = ["GAMMA_GRID", "ToneCurve", "ToneEstimate", "TonePool", "ToneState", "differs",
           "probe_costs", "sound_sides"]

# the power laws every probe re-fits (sRGB is probed as well)
GAMMA_GRID: tuple[float, ...] = (1.0, 1.6, 2.2, 2.8)
_SRGB_A = 0.055
# the curve used until the images show otherwise, and how strongly they must
DEFAULT_GAMMA = 2.2
SWITCH_COST = 0.5
SWITCH_SIGMAS = 3.0
SWITCH_GAMMA = 0.4
# ... and below the start curve by more than this: noise, and JPEG's loss of fine detail
# (a blur applied after the encoding), make edges look more linear than they are; single
# dim, defocused JPEG frames of a gamma 2.2 camera have fitted 1.46
SWITCH_GAMMA_BELOW = 0.85
# a probed side counts only where each candidate's re-fit keeps this share of the
# frame's median contrast (see sound_sides)
MIN_CONTRAST_SHARE = 0.25
# the best fit's systematic error on renders (see the module docstring), 1-sigma
_SYSTEMATIC_SIGMA = 0.15


@dataclass(frozen=True)
class ToneCurve:
    """A tone curve: ``power`` (``linear = v ** gamma``, v in 0..1) or ``srgb`` (IEC 61966-2-1).

    Attributes:
        kind: ``power`` or ``srgb``.
        gamma: the exponent of a power law; for ``srgb`` 2.2, its effective gamma.
    """

    kind: str = "power"
    gamma: float = 2.2

    @property
    def name(self) -> str:
        """``linear``, ``gamma 1.80`` or ``sRGB``."""
        if self.kind == "srgb":
            return "sRGB"
        return "linear" if self.gamma == 1.0 else f"gamma {self.gamma:.2f}"

    def to_linear(self, v: np.ndarray) -> np.ndarray:
        """Linear light (0..1) from encoded values v (0..1), same shape, float32."""
        v = np.clip(np.asarray(v, dtype=np.float32), 0.0, 1.0)
        if self.kind == "srgb":
            return np.where(v <= 0.04045, v / 12.92,
                            ((v + _SRGB_A) / (1.0 + _SRGB_A)) ** 2.4).astype(np.float32)
        if self.gamma == 1.0:
            return v
        return (v ** np.float32(self.gamma)).astype(np.float32)

    def to_encoded(self, lin: np.ndarray) -> np.ndarray:
        """Encoded values (0..1) from linear light (0..1), same shape, float32."""
        x = np.clip(np.asarray(lin, dtype=np.float32), 0.0, 1.0)
        if self.kind == "srgb":
            return np.where(x <= 0.0031308, 12.92 * x,
                            (1.0 + _SRGB_A) * x ** (1.0 / 2.4) - _SRGB_A).astype(np.float32)
        if self.gamma == 1.0:
            return x
        return (x ** np.float32(1.0 / self.gamma)).astype(np.float32)

    def linearise(self, gray: np.ndarray) -> np.ndarray:
        """(H, W) float32 linear light in 0..1 from a (H, W) uint8 or uint16 grey image."""
        if gray.dtype != np.uint8 and self.kind == "power" and self.gamma == 1.0:
            return gray.astype(np.float32) * np.float32(1.0 / 65535.0)
        if gray.dtype == np.uint8 and gray.size:
            # (OpenCV's table look-up: the same values in half numpy's indexing time)
            return np.asarray(cv2.LUT(gray, _lut(self, 255)))
        return _lut(self, 255 if gray.dtype == np.uint8 else 65535)[gray]


@lru_cache(maxsize=16)
def _lut(curve: ToneCurve, full_scale: int) -> np.ndarray:
    return curve.to_linear(np.arange(full_scale + 1, dtype=np.float64) / full_scale)


def _candidates() -> tuple[ToneCurve, ...]:
    return (*(ToneCurve("power", g) for g in GAMMA_GRID), ToneCurve("srgb"))


CANDIDATES: tuple[ToneCurve, ...] = _candidates()


@dataclass(frozen=True)
class ToneEstimate:
    """The tone curve a detector uses and how well the images determine it.

    Attributes:
        curve: the curve the detector uses (estimated, or given).
        sigma: 1-sigma of the best fit's gamma, the systematic error included (0 when
            given; inf before any evidence).
        estimated: True when it comes from the images.
        sides: sides of the images the estimate rests on.
        fitted: the best-fitting curve; ``curve`` is it when the images single it out,
            gamma 2.2 otherwise (None when given).
    """

    curve: ToneCurve
    sigma: float
    estimated: bool
    sides: int = 0
    fitted: ToneCurve | None = None

    def as_dict(self) -> dict[str, object]:
        """JSON-ready: ``gamma``, ``kind``, ``name`` (the curve used), ``sigma``,
        ``estimated``, ``sides``, ``fitted_gamma`` and ``fitted_name`` (the best fit)."""
        sigma = float(self.sigma) if np.isfinite(self.sigma) else None
        fitted = self.fitted or self.curve
        return {"gamma": round(float(self.curve.gamma), 4), "kind": self.curve.kind,
                "name": self.curve.name, "sigma": None if sigma is None else round(sigma, 4),
                "estimated": self.estimated, "sides": int(self.sides),
                "fitted_gamma": round(float(fitted.gamma), 4), "fitted_name": fitted.name}

    def text(self) -> str:
        """One line, e.g. ``gamma 2.18 +- 0.03 (estimated from 412 edges)``."""
        if not self.estimated:
            return f"{self.curve.name} (given)"
        if self.sides == 0:
            return f"{self.curve.name} (assumed: no edges yet)"
        fitted = self.fitted or self.curve
        pm = "" if fitted.kind == "srgb" or not np.isfinite(self.sigma) else (
            f" +- {self.sigma:.2f}")
        if fitted == self.curve:
            return f"{fitted.name}{pm} (estimated from {self.sides} edges)"
        return (f"{self.curve.name} (best fit {fitted.name}{pm} from {self.sides} edges: "
                "not different enough)")


# a TonePool's (costs, samples, sides, steady), see TonePool.snapshot
ToneState = tuple[np.ndarray, int, int, int]


class TonePool:
    """Step-model costs of the candidate tone curves, pooled over the frames of one camera.

    Each frame's costs enter relative to its own best candidate's, times its sides:
    a side's squared residuals relative to its contrast measure its noise as well as
    the curve's misfit, so summed as they are a dim, noisy frame's costs would be
    several times a bright frame's and decide the pool, although its residuals say
    least about the curve. Divided by the frame's lowest cost (its residual level per
    side) they are in units of that frame's noise, and a frame counts by how sharply
    its costs single out a curve.

    Attributes:
        costs: (C,) per candidate of :data:`CANDIDATES`, the sum over frames of
            ``sides * cost / lowest cost``.
        samples: samples behind them; sides: sides behind them.
        steady: sides pooled since the curve in use last changed.
    """

    # later frames are not probed once this many sides have been pooled without
    # changing the curve in use (the decision of :meth:`estimate` no longer changes,
    # see the module docstring; a change is confirmed or undone by as many sides)
    SETTLED_SIDES = 96

    def __init__(self, start: ToneCurve | None = None) -> None:
        self.start = start or ToneCurve("power", DEFAULT_GAMMA)
        self.reset()

    # The pool is one immutable (costs, samples, sides, steady) swapped at once: detection
    # adds on its thread while the node's diagnostics read the estimate on another.
    @property
    def costs(self) -> np.ndarray:
        return self._pooled[0]

    @property
    def samples(self) -> int:
        return self._pooled[1]

    @property
    def sides(self) -> int:
        return self._pooled[2]

    @property
    def steady(self) -> int:
        return self._pooled[3]

    def reset(self) -> None:
        """Forget every frame (a different camera)."""
        self._pooled: tuple[np.ndarray, int, int, int] = (np.zeros(len(CANDIDATES)), 0, 0, 0)

    def snapshot(self) -> ToneState:
        """The pool as it stands, for :meth:`restore` (its parts are never changed in place)."""
        return self._pooled

    def restore(self, state: ToneState) -> None:
        """Go back to a :meth:`snapshot`."""
        self._pooled = state

    def add(self, costs: np.ndarray, samples: int, sides: int) -> None:
        """Add one frame's (C,) candidate costs over ``samples`` samples of ``sides`` sides."""
        costs = np.asarray(costs, dtype=np.float64)
        if sides == 0 or not np.isfinite(costs).all() or costs.min() <= 0.0:
            return
        old_costs, old_samples, old_sides, steady = self._pooled
        before = self._estimate(old_costs, old_sides).curve
        new_costs = old_costs + sides * costs / costs.min()
        new_sides = old_sides + int(sides)
        changed = differs(self._estimate(new_costs, new_sides).curve, before)
        self._pooled = (new_costs, old_samples + int(samples), new_sides,
                        0 if changed else steady + sides)

    @property
    def settled(self) -> bool:
        """The curve in use has held over enough sides that further frames need not probe."""
        return self.steady >= self.SETTLED_SIDES

    def _start_cost(self, costs: np.ndarray) -> float:
        """The pooled cost of the start curve."""
        if self.start.kind == "srgb":
            return float(costs[len(GAMMA_GRID)])
        return float(np.interp(self.start.gamma, GAMMA_GRID, costs[:len(GAMMA_GRID)]))

    def estimate(self) -> ToneEstimate:
        """The curve to use so far (the start curve before, or without, strong evidence)."""
        costs, _, sides, _ = self._pooled
        return self._estimate(costs, sides)

    def _estimate(self, costs: np.ndarray, sides: int) -> ToneEstimate:
        if sides == 0:
            return ToneEstimate(self.start, float("inf"), True, 0, self.start)
        n_pow = len(GAMMA_GRID)
        power = costs[:n_pow]
        grid = np.asarray(GAMMA_GRID)
        i = int(np.argmin(power))
        j = min(max(i, 1), n_pow - 2)
        x, y = grid[j - 1:j + 2], power[j - 1:j + 2]
        c2, c1, c0 = np.polyfit(x, y, 2)
        if c2 > 0:
            gamma = float(np.clip(-c1 / (2.0 * c2), grid[0], grid[-1]))
            best = float(np.polyval((c2, c1, c0), gamma))
        else:
            gamma, best, c2 = float(grid[i]), float(power[i]), 0.0
        # the cost is a sum of squared residuals; a side's residuals are correlated
        # (one model error shapes all its profiles), so a side, not a sample, is the
        # independent unit: variance best / sides, information 2 c2 / (2 variance)
        var = max(best, 1e-12) / max(sides - 2, 1)
        stat = float(np.sqrt(var / c2)) if c2 > 0 else float("inf")
        sigma = float(np.hypot(stat, _SYSTEMATIC_SIGMA))
        fitted = ToneCurve("power", round(gamma, 3))
        # a best fit at the top of the grid, or without a minimum, identifies no curve
        # (defocused frames fit the steepest candidate best: the blur model's misfit)
        margin = SWITCH_GAMMA_BELOW if gamma < self.start.gamma else SWITCH_GAMMA
        far = ((abs(gamma - self.start.gamma) > margin or self.start.kind == "srgb")
               and np.isfinite(stat) and gamma < grid[-1])
        if costs[n_pow] < best:
            fitted, best, far = CANDIDATES[n_pow], float(costs[n_pow]), True
        start = self._start_cost(costs)
        strong = (far and start > (1.0 + SWITCH_COST) * best
                  and start - best > SWITCH_SIGMAS ** 2 * var)
        return ToneEstimate(fitted if strong else self.start, sigma, True, sides, fitted)


def differs(a: ToneCurve, b: ToneCurve) -> bool:
    """Two curves far enough apart that the edges are worth fitting again.

    (0.12 in gamma moves a sharp edge by about 0.02 px; sRGB and gamma 2.2 differ
    only in the darkest tenth, where no edge's transition is read, so sRGB counts as
    its effective gamma 2.2.)
    """
    return abs(a.gamma - b.gamma) > 0.12


def sound_sides(contrast: np.ndarray) -> np.ndarray:
    """(F,) bool: the probed sides whose step every candidate's re-fit still sees.

    A side's cost is relative to its fitted contrast ``D``; where a fit has lost the
    step (``D`` near zero or of the wrong sign: a side in noise, or laid across
    something else) that cost has no bound, and its ratio between candidates is only
    the ratio of their contrast scales, which favours the flattest curve. One such
    side on a dim frame outweighed 90 sound ones and read a gamma 2.2 camera as
    linear. So a side counts only when its contrast has one sign in every candidate
    and is at least :data:`MIN_CONTRAST_SHARE` of the median over the probed sides
    (per candidate: each reads the contrast on its own scale).

    Args:
        contrast: (C, F) the re-fitted contrast ``D`` of each candidate and side.
    """
    d = np.asarray(contrast, dtype=np.float64)
    if d.shape[1] == 0:
        return np.zeros(0, dtype=bool)
    one_sign = (np.sign(d) == np.sign(d[:1])).all(axis=0) & (d[0] != 0.0)
    typical = np.median(np.abs(d), axis=1, keepdims=True)
    return np.asarray(one_sign & (np.abs(d) >= MIN_CONTRAST_SHARE * typical).all(axis=0))


def probe_costs(fit_values: Callable[..., None], values: np.ndarray, sides: np.ndarray,
                current: ToneCurve, coef: np.ndarray, blur: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(C,) step-model costs of every candidate curve over the sound ``sides`` given, and
    (F,) bool which sides those are (:func:`sound_sides`).

    Args:
        fit_values: ``fit_values(values, coef0=, blur0=, cost_out=, contrast_out=)``
            re-fits C copies of the sides, copy c to ``values`` read through candidate c
            (the step model's fit on the probed sides' samples,
            :meth:`~artcal_ros.core.detect.edges.ProbeFit.subset` with ``copies=C``;
            C F sides, copy-major).
        values: (N,) the probed sides' samples' linear values, read through ``current``.
        sides: (F,) int, the sides probed (indices into ``coef`` and ``blur``).
        current: the curve ``values`` were read through.
        coef, blur: (S, 3), (S,) the fit at ``current``, the start of every re-fit.
    """
    encoded = current.to_encoded(values)
    n_cand, f = len(CANDIDATES), len(sides)
    stacked = np.concatenate([curve.to_linear(encoded) for curve in CANDIDATES])
    cost = np.zeros(n_cand * f)
    contrast = np.zeros(n_cand * f)
    fit_values(stacked, coef0=np.tile(coef[sides], (n_cand, 1)),
               blur0=np.tile(blur[sides], n_cand), cost_out=cost, contrast_out=contrast)
    sound = sound_sides(contrast.reshape(n_cand, f))
    return cost.reshape(n_cand, f)[:, sound].sum(axis=1), sound


# most pilot sides a frame's tone probe re-fits per candidate curve
_PROBE_SIDES = 16


class ToneProbe:
    """Keeps the last fit :func:`~artcal_ros.core.detect.edges.refine_quads` offers (a
    :class:`~artcal_ros.core.detect.edges.ProbeFit`); :meth:`commit` probes it into the pool."""

    def __init__(self, pool: TonePool, curve: ToneCurve) -> None:
        self.pool, self.curve = pool, curve
        self.last: Any = None

    def __call__(self, fit: Any) -> None:
        self.last = fit

    def commit(self) -> None:
        """The candidate curves' costs on the kept fit's sides, added to the pool."""
        if self.last is None:
            return
        fit, self.last = self.last, None
        pick = np.linspace(0, len(fit.sides) - 1, min(len(fit.sides), _PROBE_SIDES))
        sides = fit.sides[pick.astype(int)]
        fit_values, values = fit.subset(sides, copies=len(CANDIDATES))
        costs, sound = probe_costs(fit_values, values, sides, self.curve, fit.coef, fit.blur)
        counts = np.bincount(np.asarray(fit.samples.side), minlength=len(fit.coef))[sides]
        self.pool.add(costs, int(counts[sound].sum()), int(sound.sum()))
