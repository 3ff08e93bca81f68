"""The camera model of the whole package, and the registry of lens models.

One :class:`CameraModel` (lens model name, K, distortion, image size) serves detection (a
known lens for the second, lens-aware pass), calibration (results, quality figures) and the
renderer (its ground truth). The lens models are OpenCV's, named as in
sensor_msgs/CameraInfo (:data:`LENS_MODELS`):

- ``plumb_bob``: k1 k2 p1 p2 k3 (radial polynomial plus tangential terms);
- ``rational_polynomial``: k1 k2 p1 p2 k3 k4 k5 k6 (radial ratio of polynomials);
- ``equidistant``: k1 k2 k3 k4 of ``cv2.fisheye`` (theta_d = theta (1 + k1 theta^2 + ...)).

Two inverses are offered because two jobs need them: :meth:`CameraModel.rays` is the exact
inverse of :meth:`CameraModel.project` with its derivatives (Newton's method on the forward
model; the renderer draws by inverse mapping with it), and :meth:`CameraModel.undistort` /
:meth:`CameraModel.unproject` are OpenCV's iterative inverses (what a calibration's user
gets from ``cv2.undistortPoints``). Pixel coordinates are OpenCV's: the centre of the
top-left pixel is (0, 0). Skew is always zero.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, TypeVar

import cv2
import numpy as np

from artcal_ros.core.errors import ParameterError

_C = TypeVar("_C", bound="CameraModel")


@dataclass(frozen=True)
class LensSpec:
    """One lens model of the registry.

    Attributes:
        name: the CameraInfo ``distortion_model`` name.
        dist_names: its coefficients in OpenCV order.
        radial: the radial coefficients among them, in the order they are freed
            (``calibrate.k_coefficients`` counts these).
        tangential: whether p1, p2 are part of the model.
        default_radial: radial terms solved by default.
    """

    name: str
    dist_names: tuple[str, ...]
    radial: tuple[str, ...]
    tangential: bool
    default_radial: int

    @property
    def n_dist(self) -> int:
        """Number of distortion coefficients."""
        return len(self.dist_names)


LENS_MODELS: dict[str, LensSpec] = {
    "plumb_bob": LensSpec("plumb_bob", ("k1", "k2", "p1", "p2", "k3"), ("k1", "k2", "k3"),
                          True, 2),
    "rational_polynomial": LensSpec(
        "rational_polynomial", ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
        ("k1", "k2", "k3", "k4", "k5", "k6"), True, 6),
    "equidistant": LensSpec("equidistant", ("k1", "k2", "k3", "k4"), ("k1", "k2", "k3", "k4"),
                            False, 4),
}
MODELS: tuple[str, ...] = tuple(LENS_MODELS)

# OpenCV's iterative undistortion, as precise as float64 allows
_CV_CRITERIA = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
_CV_CRITERIA_EXACT = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 500, 1e-15)


def lens_spec(model: str) -> LensSpec:
    """The registry entry of ``model``.

    Raises:
        ParameterError: ``model`` is not one of :data:`MODELS`.
    """
    spec = LENS_MODELS.get(model)
    if spec is None:
        raise ParameterError(f"camera model {model!r} is not one of {', '.join(MODELS)}")
    return spec


@dataclass(frozen=True, eq=False)
class CameraModel:
    """An intrinsically calibrated camera.

    Attributes:
        model: a name of :data:`LENS_MODELS`.
        K: (3, 3) float64 camera matrix, pixels (zero skew).
        dist: (n,) float64 distortion in OpenCV order (5 for plumb_bob, a 4-element one is
            padded with k3 = 0; 8 for rational_polynomial; 4 for equidistant).
        size: (width, height) of the image, pixels.

    Raises:
        ParameterError: an unknown model, a wrong number of coefficients, a bad matrix or size.
    """

    model: str
    K: np.ndarray
    dist: np.ndarray
    size: tuple[int, int]
    # memo of derived per-pixel tables (see the renderer); not part of the value
    _cache: dict[str, Any] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        spec = lens_spec(self.model)
        K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        dist: np.ndarray = np.asarray(self.dist, dtype=np.float64).ravel()
        if self.model == "plumb_bob" and dist.size == 4:
            dist = np.append(dist, 0.0)
        if dist.size != spec.n_dist:
            raise ParameterError(f"camera model {self.model} needs {spec.n_dist} distortion "
                                 f"coefficients, got {dist.size}")
        if K[0, 1] != 0.0 or not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ParameterError("camera matrix must have positive focal lengths and zero skew")
        w, h = (int(self.size[0]), int(self.size[1]))
        if w < 8 or h < 8:
            raise ParameterError(f"image size {w}x{h} is too small (at least 8x8 pixels)")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "size", (w, h))

    @property
    def width(self) -> int:
        return self.size[0]

    @property
    def height(self) -> int:
        return self.size[1]

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description: model, K (row-major 3x3), dist, width, height."""
        return {"model": self.model, "K": self.K.tolist(), "dist": self.dist.tolist(),
                "width": self.width, "height": self.height}

    @classmethod
    def from_dict(cls: type[_C], d: dict[str, Any]) -> _C:
        """The inverse of :meth:`to_dict`."""
        return cls(str(d["model"]), np.array(d["K"], dtype=np.float64),
                   np.array(d["dist"], dtype=np.float64), (int(d["width"]), int(d["height"])))

    # --- forward model (numpy, OpenCV's formulas) -----------------------------------------
    def project(self, points: np.ndarray, rvec: np.ndarray | None = None,
                tvec: np.ndarray | None = None) -> np.ndarray:
        """Project 3-D points with the forward model (OpenCV's, to < 1e-9 px).

        Args:
            points: (N, 3) float64, metres; in the camera frame, or in the board frame when
                ``rvec``/``tvec`` (T_cam_board, Rodrigues vector and translation in metres)
                are given.

        Returns:
            (N, 2) float64 pixels. Points at or behind the camera plane (z <= 0) give NaN.
        """
        P = _as_cam_points(points, rvec, tvec)
        z = P[:, 2]
        front = z > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.where(front, P[:, 0] / z, np.nan)
            b = np.where(front, P[:, 1] / z, np.nan)
            if self.model == "equidistant":
                r = np.hypot(a, b)
                theta = np.arctan(r)
                theta_d, _ = _theta_d(self.dist, theta)
                scale = np.where(r > 1e-8, theta_d / np.where(r > 1e-8, r, 1.0), 1.0)
                xd, yd = a * scale, b * scale
            else:
                xd, yd = self.distort_normalized(a, b)[:2]
        K = self.K
        return np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)

    def distort_normalized(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, ...]:
        """Pinhole models: undistorted normalized (x, y) -> distorted (xd, yd) and the Jacobian.

        Returns ``xd, yd, dxd_dx, dxd_dy, dyd_dx, dyd_dy`` (arrays shaped like ``x``).
        """
        p1, p2 = self.dist[2], self.dist[3]
        r2 = x * x + y * y
        rad, drad = _radial_pinhole(self.dist, r2)
        xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        cross = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
        a = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
        d = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
        return xd, yd, a, cross, cross, d

    def field_radius(self, points_cam: np.ndarray) -> np.ndarray:
        """(N,) undistorted field radius of camera-frame points: tan of the angle off the axis
        (radians for equidistant)."""
        P = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
        rho = np.hypot(P[:, 0], P[:, 1])
        if self.model == "equidistant":
            return np.asarray(np.arctan2(rho, P[:, 2]))
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(P[:, 2] > 0, rho / P[:, 2], np.inf)

    # --- exact inverse (Newton on the forward model) ---------------------------------------
    def rays(self, u: np.ndarray,
             v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Viewing rays of pixels (the exact inverse of :meth:`project`).

        Args:
            u, v: same-shape arrays of pixel coordinates.

        Returns:
            ray, ray_du, ray_dv: (..., 3) ray directions (camera frame, any positive scale)
            and their derivatives per pixel in u and v; valid: (...) bool where the inverse
            exists.
        """
        K = self.K
        fx, fy = K[0, 0], K[1, 1]
        qx = (u - K[0, 2]) / fx
        qy = (v - K[1, 2]) / fy
        if self.model != "equidistant":
            x, y, ia, ib, ic, id_, valid = self._undistort_pinhole(qx, qy)
            ray = np.stack([x, y, np.ones_like(x)], axis=-1)
            zero = np.zeros_like(x)
            ray_du = np.stack([ia / fx, ic / fx, zero], axis=-1)
            ray_dv = np.stack([ib / fy, id_ / fy, zero], axis=-1)
            return ray, ray_du, ray_dv, valid
        theta, dtheta, valid = self._undistort_equidistant(qx, qy)
        rho = np.hypot(qx, qy)
        small = rho < 1e-9
        rho_s = np.where(small, 1.0, rho)
        sin_t, cos_t = np.sin(theta), np.cos(theta)
        s = np.where(small, dtheta, sin_t / rho_s)                 # sin(theta) / rho
        ds = np.where(small, 0.0, (cos_t * dtheta * rho_s - sin_t) / (rho_s * rho_s))
        ux, uy = np.where(small, 0.0, qx / rho_s), np.where(small, 0.0, qy / rho_s)
        ray = np.stack([s * qx, s * qy, cos_t], axis=-1)
        # d/dq of (s q, cos theta): s I + s'(rho) q q^T / rho and -sin(theta) theta' q / rho
        dz = -sin_t * dtheta
        ray_du = np.stack([s + ds * qx * ux, ds * qy * ux, dz * ux], axis=-1) / fx
        ray_dv = np.stack([ds * qx * uy, s + ds * qy * uy, dz * uy], axis=-1) / fy
        return ray, ray_du, ray_dv, valid

    def _undistort_pinhole(self, qx: np.ndarray, qy: np.ndarray,
                           iterations: int = 30) -> tuple[np.ndarray, ...]:
        """Newton's method on distort(x, y) = (qx, qy). Returns x, y, inverse Jacobian, valid."""
        # start from the radial-only inverse at the distorted radius: close enough for Newton
        rad0, _ = _radial_pinhole(self.dist, qx * qx + qy * qy)
        rad0 = np.where(rad0 > 0.2, rad0, 0.2)
        x, y = qx / rad0, qy / rad0
        for _ in range(iterations):
            xd, yd, a, b, c, d = self.distort_normalized(x, y)
            ex, ey = xd - qx, yd - qy
            det = a * d - b * c
            if float(np.max(np.abs(ex))) < 1e-13 and float(np.max(np.abs(ey))) < 1e-13:
                break
            det_s = np.where(np.abs(det) < 1e-12, 1e-12, det)
            sx = (d * ex - b * ey) / det_s
            sy = (a * ey - c * ex) / det_s
            # damp huge steps so a far start cannot jump across the fold of the polynomial
            n = np.hypot(sx, sy)
            damp = np.minimum(1.0, 0.25 / np.maximum(n, 1e-300))
            x -= sx * damp
            y -= sy * damp
        resid = np.hypot(ex * self.K[0, 0], ey * self.K[1, 1])
        valid = (det > 1e-9) & (resid < 1e-7)
        det = np.where(valid, det, 1.0)
        inv = (d / det, -b / det, -c / det, a / det)
        return (x, y, *inv, valid)

    def _undistort_equidistant(self, qx: np.ndarray,
                               qy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """theta from theta_d = |q| (1-D Newton). Returns theta, d theta / d theta_d, valid."""
        theta_d = np.hypot(qx, qy)
        theta = theta_d.copy()
        for _ in range(30):
            f, df = _theta_d(self.dist, theta)
            step = (f - theta_d) / np.where(np.abs(df) < 1e-12, 1e-12, df)
            theta -= np.clip(step, -0.2, 0.2)
            if float(np.max(np.abs(f - theta_d))) < 1e-13:
                break
        f, df = _theta_d(self.dist, theta)
        valid = (df > 1e-9) & (np.abs(f - theta_d) * self.K[0, 0] < 1e-7) & (theta < np.pi)
        return theta, 1.0 / np.where(df > 1e-12, df, 1e-12), valid

    # --- OpenCV's inverse and forward map, in pixels ---------------------------------------
    def undistort(self, pts_px: np.ndarray) -> np.ndarray:
        """(N, 2) image pixels -> (N, 2) undistorted pixels (same K), OpenCV's iteration."""
        p = np.asarray(pts_px, dtype=np.float64).reshape(-1, 1, 2)
        if len(p) == 0:
            return np.zeros((0, 2))
        if self.model == "equidistant":
            out = cv2.fisheye.undistortPoints(p, self.K, self.dist[:4], P=self.K,
                                              criteria=_CV_CRITERIA)
        else:
            out = cv2.undistortPointsIter(p, self.K, self.dist, None, self.K,  # type: ignore
                                          _CV_CRITERIA)
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)

    def distort(self, pts_px: np.ndarray) -> np.ndarray:
        """(N, 2) undistorted pixels -> (N, 2) image pixels (OpenCV's projection)."""
        p = np.asarray(pts_px, dtype=np.float64).reshape(-1, 2)
        if len(p) == 0:
            return np.zeros((0, 2))
        Kinv = np.linalg.inv(self.K)
        xy = (np.c_[p, np.ones(len(p))] @ Kinv.T)[:, :2]
        if self.model == "equidistant":
            # OpenCV reads the buffer as packed: a strided view would be misread
            out = cv2.fisheye.distortPoints(np.ascontiguousarray(xy).reshape(-1, 1, 2), self.K,
                                            self.dist[:4])
        else:
            obj = np.c_[xy, np.ones(len(xy))].reshape(-1, 1, 3)
            out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), self.K, self.dist)
        return np.asarray(out, dtype=np.float64).reshape(-1, 2)

    def project_cv(self, rays: np.ndarray) -> np.ndarray:
        """(N, 2) pixels where camera-frame rays (N, 3) land, by OpenCV's projection."""
        obj = np.ascontiguousarray(rays, dtype=np.float64).reshape(-1, 1, 3)
        zero = np.zeros((3, 1))
        if self.model == "equidistant":
            img, _ = cv2.fisheye.projectPoints(obj, zero, zero, self.K,
                                               self.dist.reshape(4, 1))
        else:
            img, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), self.K, self.dist)
        return np.asarray(img, dtype=np.float64).reshape(-1, 2)

    def unproject(self, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays of image points by OpenCV's inverse: ((N, 3) rays with z = 1, (N,) bool where
        the inverse is exact, i.e. re-projecting the ray lands within 1e-4 px)."""
        pts = np.ascontiguousarray(pixels, dtype=np.float64).reshape(-1, 1, 2)
        if self.model == "equidistant":
            und = cv2.fisheye.undistortPoints(pts, self.K, self.dist.reshape(4, 1),
                                              criteria=_CV_CRITERIA_EXACT)
        else:
            und = cv2.undistortPointsIter(pts, self.K, self.dist, np.eye(3), np.eye(3),
                                          _CV_CRITERIA_EXACT)
        rays = np.hstack([und.reshape(-1, 2), np.ones((len(pts), 1))])
        back = self.project_cv(rays)
        ok = np.linalg.norm(back - pts.reshape(-1, 2), axis=1) < 1e-4
        return rays, ok


def _as_cam_points(points: np.ndarray, rvec: np.ndarray | None,
                   tvec: np.ndarray | None) -> np.ndarray:
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    if rvec is None and tvec is None:
        return pts
    R = cv2.Rodrigues(np.asarray(rvec if rvec is not None else np.zeros(3),
                                 dtype=np.float64).reshape(3, 1))[0]
    t = np.asarray(tvec if tvec is not None else np.zeros(3), dtype=np.float64).reshape(3)
    return np.asarray(pts @ R.T + t)


def _radial_pinhole(dist: np.ndarray, r2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Radial factor and its derivative with respect to r^2 (pinhole models)."""
    k = np.zeros(8)
    k[:dist.size] = dist
    k1, k2, _, _, k3, k4, k5, k6 = k
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
    return num / den, (dnum * den - num * dden) / (den * den)


def _theta_d(dist: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Equidistant model: theta_d(theta) and d theta_d / d theta."""
    k1, k2, k3, k4 = dist
    t2 = theta * theta
    poly = 1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
    dpoly = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    return theta * poly, dpoly


class HasCamera(Protocol):
    """Anything that carries a calibrated camera: a CalibrationResult, a CameraInfoData."""

    @property
    def camera(self) -> CameraModel: ...


def camera_of(source: CameraModel | HasCamera) -> CameraModel:
    """``source`` itself if it is a camera, else the camera it carries."""
    return source if isinstance(source, CameraModel) else source.camera
