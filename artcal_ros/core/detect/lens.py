"""A known lens model for detection: map pixels to undistorted pixels and back.

Detection uses it on a second pass after a first calibration: border edges
are fitted as straight lines in undistorted coordinates (where the marker's
sides really are straight) and the corners and centres are mapped back.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.errors import DetectionError

_MODELS = ("plumb_bob", "rational_polynomial", "equidistant")
_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@dataclass(frozen=True)
class LensModel:
    """Camera matrix and distortion of a lens.

    Attributes:
        K: (3, 3) float64 camera matrix, pixels.
        dist: (n,) float64 distortion coefficients in OpenCV order.
        model: ``plumb_bob``, ``rational_polynomial`` or ``equidistant``.
    """

    K: np.ndarray
    dist: np.ndarray
    model: str = "plumb_bob"

    @classmethod
    def from_any(cls, camera: Any) -> LensModel:
        """From ``(K, dist, model)``, ``(K, dist)`` or an object with K/dist/model attributes."""
        if isinstance(camera, LensModel):
            return camera
        if isinstance(camera, tuple | list):
            K, dist = camera[0], camera[1]
            model = camera[2] if len(camera) > 2 else "plumb_bob"
        else:
            K = getattr(camera, "K", getattr(camera, "camera_matrix", None))
            dist = getattr(camera, "dist", getattr(camera, "dist_coeffs", None))
            model = getattr(camera, "model", "plumb_bob")
        if K is None or dist is None:
            raise DetectionError("camera: expected (K, dist, model) or an object with K, "
                                 "dist and model attributes")
        K = np.asarray(K, dtype=np.float64).reshape(3, 3)
        dist = np.asarray(dist, dtype=np.float64).ravel()
        if model not in _MODELS:
            raise DetectionError(f"camera model {model!r} is not one of {', '.join(_MODELS)}")
        return cls(K, dist, str(model))

    def undistort(self, pts_px: np.ndarray) -> np.ndarray:
        """(N, 2) image pixels -> (N, 2) undistorted pixels (same K)."""
        p = np.asarray(pts_px, dtype=np.float64).reshape(-1, 1, 2)
        if len(p) == 0:
            return np.zeros((0, 2))
        if self.model == "equidistant":
            out = cv2.fisheye.undistortPoints(p, self.K, self.dist[:4], P=self.K,
                                              criteria=_CRITERIA)
        else:
            out = cv2.undistortPointsIter(p, self.K, self.dist, None, self.K,  # type: ignore
                                          _CRITERIA)
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)

    def distort(self, pts_px: np.ndarray) -> np.ndarray:
        """(N, 2) undistorted pixels -> (N, 2) image pixels."""
        p = np.asarray(pts_px, dtype=np.float64).reshape(-1, 2)
        if len(p) == 0:
            return np.zeros((0, 2))
        Kinv = np.linalg.inv(self.K)
        xy = (np.c_[p, np.ones(len(p))] @ Kinv.T)[:, :2]
        if self.model == "equidistant":
            out = cv2.fisheye.distortPoints(xy.reshape(-1, 1, 2), self.K, self.dist[:4])
        else:
            obj = np.c_[xy, np.ones(len(xy))].reshape(-1, 1, 3)
            out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), self.K, self.dist)
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)


@dataclass(frozen=True)
class DivisionLens:
    """Division model of radial distortion, estimated from the image itself (plumb lines).

    ``p_u = c + (p_d - c) / (1 + lam * r^2 + lam2 * r^4 + lam3 * r^6)`` with
    ``r = |p_d - c| / scale`` maps image pixels ``p_d`` to pixels where the
    board's straight edges are straight again.

    Attributes:
        lam: r^2 coefficient (negative: barrel), dimensionless.
        centre: (2,) distortion centre, pixels.
        scale: radius normalisation, pixels (the image's half diagonal).
        lam2: r^4 coefficient.
        lam3: r^6 coefficient.
        significance: |lam| over its standard deviation when estimated.
    """

    lam: float
    centre: np.ndarray
    scale: float
    lam2: float = 0.0
    lam3: float = 0.0
    significance: float = float("inf")

    def _factor(self, d: np.ndarray) -> np.ndarray:
        r2 = (d * d).sum(axis=1, keepdims=True) / self.scale**2
        return 1.0 + r2 * (self.lam + r2 * (self.lam2 + r2 * self.lam3))

    def undistort(self, pts_px: np.ndarray) -> np.ndarray:
        """(N, 2) image pixels -> (N, 2) straightened pixels."""
        d = np.asarray(pts_px, dtype=np.float64).reshape(-1, 2) - self.centre
        return self.centre + d / self._factor(d)

    def distort(self, pts_px: np.ndarray) -> np.ndarray:
        """(N, 2) straightened pixels -> (N, 2) image pixels.

        Newton's method on the radius: ``r_d = r_u (1 + lam r_d^2 + lam2 r_d^4 + lam3 r_d^6)``.
        """
        du = np.asarray(pts_px, dtype=np.float64).reshape(-1, 2) - self.centre
        ru = np.hypot(du[:, 0], du[:, 1]) / self.scale
        rd = ru.copy()
        for _ in range(20):
            r2 = rd * rd
            g = rd - ru * (1.0 + r2 * (self.lam + r2 * (self.lam2 + r2 * self.lam3)))
            dg = 1.0 - ru * rd * (2.0 * self.lam + r2 * (4.0 * self.lam2 + 6.0 * self.lam3 * r2))
            with np.errstate(all="ignore"):
                step = g / dg
            step = np.nan_to_num(step)
            rd -= step
            if np.abs(step).max(initial=0.0) < 1e-13:
                break
        with np.errstate(all="ignore"):
            gain = np.where(ru > 0, rd / ru, 1.0)
        return self.centre + du * gain[:, None]


class LensPool:
    """Plumb-line evidence about the lens, pooled over the frames of one camera.

    A single frame's few short sides determine the distortion only roughly; the
    lens does not change between frames, so :class:`~artcal_ros.core.detect.Detector`
    adds every frame's normal equations here and each new frame is fitted with
    all of them. Reset it (``Detector.reset_lens()``) when the camera changes;
    a change of image size resets it by itself.

    Attributes:
        info: (3, 3) summed information about (lam, lam2, lam3).
        info_theta: (2,) summed information-weighted estimates.
        shape: (height, width) of the images pooled so far.
    """

    def __init__(self) -> None:
        self.info = np.zeros((3, 3))
        self.info_theta = np.zeros(3)
        self.shape: tuple[int, ...] = ()

    def reset(self, shape: tuple[int, ...] = ()) -> None:
        """Forget everything (and remember the new image size)."""
        self.info = np.zeros((3, 3))
        self.info_theta = np.zeros(3)
        self.shape = shape
