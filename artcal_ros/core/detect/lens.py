"""Lenses for detection: a known camera, or a division model estimated from the image.

With a known camera (a second pass after a first calibration) border edges are fitted as
straight lines in undistorted coordinates, where the marker's sides really are straight, and
the corners and centers are mapped back. Without one, the plumb-line estimate
(:mod:`.plumb`) gives a :class:`DivisionLens`, pooled over a stream's frames by
:class:`LensPool`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from artcal_ros.core.camera import CameraModel, HasCamera, camera_of
from artcal_ros.core.errors import DetectionError


@dataclass(frozen=True)
class DivisionLens:
    """Division model of radial distortion, estimated from the image itself (plumb lines).

    ``p_u = c + (p_d - c) / (1 + lam * r^2 + lam2 * r^4 + lam3 * r^6)`` with
    ``r = |p_d - c| / scale`` maps image pixels ``p_d`` to pixels where the
    board's straight edges are straight again.

    Attributes:
        lam: r^2 coefficient (negative: barrel), dimensionless.
        center: (2,) distortion center, pixels.
        scale: radius normalisation, pixels (the image's half diagonal).
        lam2: r^4 coefficient.
        lam3: r^6 coefficient.
        significance: |lam| over its standard deviation when estimated.
        bend_misfit: per band of :data:`BEND_BANDS`, the variance of the curvature of a
            straight edge's image that the model misses there, px^-2, as the sides' own
            curvature shows it (:mod:`.bends`; empty: none known).
    """

    lam: float
    center: np.ndarray
    scale: float
    lam2: float = 0.0
    lam3: float = 0.0
    significance: float = float("inf")
    bend_misfit: tuple[float, ...] = ()

    def undistort(self, pts_px: np.ndarray) -> np.ndarray:
        """(N, 2) image pixels -> (N, 2) straightened pixels."""
        p = np.ascontiguousarray(pts_px, dtype=np.float64).reshape(-1, 2)
        return division_undistort(p, np.asarray(self.center, np.float64), float(self.scale),
                                  self.lam, self.lam2, self.lam3)

    def distort(self, pts_px: np.ndarray) -> np.ndarray:
        """(N, 2) straightened pixels -> (N, 2) image pixels.

        Solves ``r_u = r_d / f(r_d)`` on the branch that starts at the centre (where
        ``r_d / f(r_d)`` increases); a point beyond that branch's end maps to its end.
        """
        p = np.ascontiguousarray(pts_px, dtype=np.float64).reshape(-1, 2)
        return _division_distort(p, np.asarray(self.center, np.float64), float(self.scale),
                                 self.lam, self.lam2, self.lam3)

    def fold_radius(self) -> float:
        """Normalised radius (``r`` above) where the model stops being one to one.

        Beyond it ``r / f(r)`` no longer increases (or ``f`` is no longer positive): a
        strong barrel model folds there, and points farther out have no straightened image.
        """
        return float(division_fold_radius(self.lam, self.lam2, self.lam3))

    def one_to_one(self, pts_px: np.ndarray) -> np.ndarray:
        """(N,) bool: the image points (N, 2) inside the fold radius."""
        p = np.asarray(pts_px, dtype=np.float64).reshape(-1, 2)
        r = np.linalg.norm(p - np.asarray(self.center, np.float64), axis=1) / self.scale
        return np.asarray(r < self.fold_radius())


# the fold search: radii up to FOLD_MAX (four times the image's half diagonal) in FOLD_STEP
# steps, then bisection; a model that does not fold there is taken as one that does not fold
FOLD_MAX = 4.0
FOLD_STEP = 0.01


@njit(cache=True, error_model="numpy", nogil=True)
def _unfolded(r: float, lam: float, lam2: float, lam3: float) -> bool:
    """Whether ``r / f(r)`` still increases at normalised radius ``r`` with ``f`` positive."""
    r2 = r * r
    f = 1.0 + r2 * (lam + r2 * (lam2 + r2 * lam3))
    # d(r / f)/dr has the sign of f - r f'(r)
    rdf = r2 * (2.0 * lam + r2 * (4.0 * lam2 + 6.0 * lam3 * r2))
    return f > 0.0 and f - rdf > 0.0


@njit(cache=True, error_model="numpy", nogil=True)
def division_fold_radius(lam: float, lam2: float, lam3: float) -> float:
    """First normalised radius where ``r / f(r)`` stops increasing; FOLD_MAX if none below."""
    r = 0.0
    while r < FOLD_MAX:
        if not _unfolded(r + FOLD_STEP, lam, lam2, lam3):
            lo, hi = r, r + FOLD_STEP
            for _ in range(30):
                mid = 0.5 * (lo + hi)
                if _unfolded(mid, lam, lam2, lam3):
                    lo = mid
                else:
                    hi = mid
            return lo
        r += FOLD_STEP
    return FOLD_MAX


@njit(cache=True, error_model="numpy", nogil=True)
def division_undistort(pts: np.ndarray, center: np.ndarray, scale: float, lam: float,
                       lam2: float, lam3: float) -> np.ndarray:
    """(N, 2) image pixels -> straightened pixels under a division model (see DivisionLens)."""
    out = np.empty_like(pts)
    for i in range(len(pts)):
        dx, dy = pts[i, 0] - center[0], pts[i, 1] - center[1]
        r2 = (dx * dx + dy * dy) / scale**2
        f = 1.0 + r2 * (lam + r2 * (lam2 + r2 * lam3))
        out[i, 0] = center[0] + dx / f
        out[i, 1] = center[1] + dy / f
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def _newton_radius(ru: float, lam: float, lam2: float, lam3: float) -> float:
    """Newton's method for ``r_d = r_u f(r_d)`` from ``r_u f(r_u)``; -1 if not converged."""
    r2 = ru * ru
    rd = ru * (1.0 + r2 * (lam + r2 * (lam2 + r2 * lam3)))
    step = 0.0
    for it in range(20):
        r2 = rd * rd
        g = rd - ru * (1.0 + r2 * (lam + r2 * (lam2 + r2 * lam3)))
        dg = 1.0 - ru * rd * (2.0 * lam + r2 * (4.0 * lam2 + 6.0 * lam3 * r2))
        step = g / dg
        if not np.isfinite(step):
            return -1.0
        rd -= step
        if it >= 3 and abs(step) < 1e-13:
            return rd
    return rd if abs(step) < 1e-9 else -1.0


@njit(cache=True, error_model="numpy", nogil=True)
def _bracketed_radius(ru: float, lam: float, lam2: float, lam3: float, fold: float,
                      top: float) -> float:
    """The root of ``r - r_u f(r)`` on [0, top): Newton's method kept inside the bracket,
    bisecting when a step leaves it (``h`` is negative below the root, positive above)."""
    lo, hi = 0.0, top
    r2 = ru * ru
    rd = ru * (1.0 + r2 * (lam + r2 * (lam2 + r2 * lam3)))
    if not lo < rd < hi:
        rd = 0.5 * fold if hi < np.inf else ru
    for _ in range(60):
        r2 = rd * rd
        g = rd - ru * (1.0 + r2 * (lam + r2 * (lam2 + r2 * lam3)))
        if g > 0.0:
            hi = rd
        else:
            lo = rd
        dg = 1.0 - ru * rd * (2.0 * lam + r2 * (4.0 * lam2 + 6.0 * lam3 * r2))
        nxt = rd - g / dg if dg != 0.0 else -1.0
        if not lo < nxt < hi:
            nxt = 0.5 * (lo + hi) if hi < np.inf else 2.0 * rd + 1e-3
        done = abs(nxt - rd) < 1e-13 or hi - lo < 1e-13
        rd = nxt
        if done:
            break
    return rd


@njit(cache=True, error_model="numpy", nogil=True)
def _division_distort(pts: np.ndarray, center: np.ndarray, scale: float, lam: float,
                      lam2: float, lam3: float) -> np.ndarray:
    """(N, 2) straightened pixels -> image pixels (see :meth:`DivisionLens.distort`)."""
    out = np.empty_like(pts)
    fold = division_fold_radius(lam, lam2, lam3)
    r2 = fold * fold
    f_fold = 1.0 + r2 * (lam + r2 * (lam2 + r2 * lam3))
    # the largest straightened radius the one-to-one branch reaches (none without a fold)
    ru_max = fold / f_fold if fold < FOLD_MAX and f_fold > 0.0 else np.inf
    top = fold if fold < FOLD_MAX else np.inf
    for i in range(len(pts)):
        dx, dy = pts[i, 0] - center[0], pts[i, 1] - center[1]
        ru = math.sqrt(dx * dx + dy * dy) / scale
        if ru >= ru_max:
            rd = fold
        else:
            rd = _newton_radius(ru, lam, lam2, lam3)
            # h(r) = r - ru f(r) has one root on [0, fold], the one wanted; Newton's method
            # from r_u f(r_u) (a few steps, no test: independent points overlap in the CPU)
            # finds it for most points, but for a strong barrel lens that first guess can
            # be far off, even negative, and Newton then ends at another root of the
            # polynomial: those points are solved again inside the bracket
            if not 0.0 <= rd < top:
                rd = _bracketed_radius(ru, lam, lam2, lam3, fold, top)
        gain = rd / ru if ru > 0 else 1.0
        out[i, 0] = center[0] + dx * gain
        out[i, 1] = center[1] + dy * gain
    return out


# bands of distance from the image centre (lower edges, in half diagonals) in which a
# division lens's bends are checked against the sides' own curvature (:mod:`.bends`)
BEND_BANDS = (0.0, 0.5, 0.65, 0.75, 0.85, 0.9, 0.95)


# A lens detection can map through: a known camera (the one CameraModel of the package, e.g.
# a previous calibration) or the division model estimated from the image itself. Both offer
# ``undistort`` and ``distort`` in pixels.
Lens = CameraModel | DivisionLens


def known_lens(camera: CameraModel | HasCamera) -> CameraModel:
    """The camera of a ``camera=`` argument: a CameraModel, or a result that carries one.

    Raises:
        DetectionError: ``camera`` is neither.
    """
    try:
        lens = camera_of(camera)
    except AttributeError:
        lens = None
    if not isinstance(lens, CameraModel):
        raise DetectionError(f"camera: expected a CameraModel (or a calibration result), got "
                             f"{type(camera).__name__}")
    return lens


class LensPool:
    """Plumb-line evidence about the lens, pooled over the frames of one camera.

    A single frame's few short sides determine the distortion only roughly; the
    lens does not change between frames, so :class:`~artcal_ros.core.detect.Detector`
    adds every frame's normal equations here and each new frame is fitted with
    all of them. Reset it (``Detector.reset_lens()``) when the camera changes;
    a change of image size resets it by itself.

    Attributes:
        info: (3, 3) summed information about (lam, lam2, lam3).
        info_theta: (3,) summed information-weighted estimates.
        bend_evidence: (5, len(BEND_BANDS)) the sides' curvature against the lens's bends,
            summed per band (:func:`~artcal_ros.core.detect.bends.trusted_bends`).
        shape: (height, width) of the images pooled so far.
    """

    def __init__(self) -> None:
        self.info = np.zeros((3, 3))
        self.info_theta = np.zeros(3)
        self.bend_evidence = np.zeros((5, len(BEND_BANDS)))
        self.shape: tuple[int, ...] = ()

    def reset(self, shape: tuple[int, ...] = ()) -> None:
        """Forget everything (and remember the new image size)."""
        self.info = np.zeros((3, 3))
        self.info_theta = np.zeros(3)
        self.bend_evidence = np.zeros((5, len(BEND_BANDS)))
        self.shape = shape

    def snapshot(self) -> LensPoolState:
        """The pooled evidence as it stands, for :meth:`restore`."""
        return LensPoolState(self.info.copy(), self.info_theta.copy(), self.shape,
                             self.bend_evidence.copy())

    def restore(self, state: LensPoolState) -> None:
        """Go back to a :meth:`snapshot` (a frame's evidence withdrawn to be fitted again)."""
        self.info = state.info.copy()
        self.info_theta = state.info_theta.copy()
        self.shape = state.shape
        self.bend_evidence = state.bend_evidence.copy()


@dataclass(frozen=True)
class LensPoolState:
    """A :class:`LensPool`'s evidence at one moment (copies; see :meth:`LensPool.snapshot`)."""

    info: np.ndarray
    info_theta: np.ndarray
    shape: tuple[int, ...]
    bend_evidence: np.ndarray
