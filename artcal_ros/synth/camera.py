"""Camera models of the renderer: presets, OpenCV's forward projection and its exact inverse.

The forward models are OpenCV's, written out in numpy so the renderer and the
ground truth share one definition that agrees with ``cv2.projectPoints`` and
``cv2.fisheye.projectPoints`` to far below 1e-6 px:

- ``plumb_bob``: k1 k2 p1 p2 [k3] (radial polynomial plus tangential terms);
- ``rational_polynomial``: k1 k2 p1 p2 k3 k4 k5 k6 (radial ratio of polynomials);
- ``equidistant``: k1 k2 k3 k4 of ``cv2.fisheye`` (theta_d = theta (1 + k1 theta^2 + ...)).

The inverse (pixel -> viewing ray) is solved by Newton's method on the forward
model, so rendering by inverse mapping draws exactly what the forward model
projects. Pixel coordinates are OpenCV's: the centre of the top-left pixel is
(0, 0).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.errors import ParameterError

MODELS = ("plumb_bob", "rational_polynomial", "equidistant")

# name -> (model, (width, height), fx, fy, cx, cy, dist); plausible lenses of each kind
_PRESETS: dict[str, tuple[str, tuple[int, int], float, float, float, float, tuple[float, ...]]] = {
    # a cheap 640x480 webcam: strong barrel distortion, slightly off-centre sensor
    "webcam": ("plumb_bob", (640, 480), 600.0, 601.5, 322.4, 236.7,
               (-0.35, 0.15, 0.0012, -0.0008, 0.0)),
    # a 1080p machine-vision camera with a mild lens
    "hd": ("plumb_bob", (1920, 1080), 1400.0, 1399.0, 963.2, 537.1,
           (-0.09, 0.06, 0.0004, -0.0003, 0.0)),
    # a wide-angle 1280x800 lens: strong radial distortion that needs k3
    "wide": ("plumb_bob", (1280, 800), 700.0, 700.8, 641.9, 402.3,
             (-0.28, 0.09, 0.0006, 0.0004, -0.012)),
    # an equidistant fisheye (cv2.fisheye model), about 170 degrees across the diagonal
    "fisheye": ("equidistant", (1024, 768), 350.0, 350.4, 514.1, 381.6,
                (0.04, -0.012, 0.003, -0.0004)),
}
PRESETS = tuple(_PRESETS)

# pixels per block in vectorised per-pixel work (keeps numpy temporaries in cache)
CHUNK = 65536


@dataclass(frozen=True, eq=False)
class Camera:
    """An intrinsically calibrated camera (the renderer's truth).

    Attributes:
        model: ``plumb_bob`` | ``rational_polynomial`` | ``equidistant``.
        K: (3, 3) float64 camera matrix, pixels (zero skew).
        dist: (n,) float64 distortion in OpenCV order (5 or 8 for the pinhole models, 4 for
            equidistant).
        size: (width, height) of the image, pixels.
    """

    model: str
    K: np.ndarray
    dist: np.ndarray
    size: tuple[int, int]
    _cache: dict[str, Any] = field(default_factory=dict, init=False, repr=False)

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ParameterError(f"camera model {self.model!r} is not one of {', '.join(MODELS)}")
        K = np.asarray(self.K, dtype=np.float64).reshape(3, 3)
        want = {"plumb_bob": (5,), "rational_polynomial": (8,), "equidistant": (4,)}[self.model]
        dist: np.ndarray = np.asarray(self.dist, dtype=np.float64).ravel()
        if self.model == "plumb_bob" and dist.size == 4:
            dist = np.append(dist, 0.0)
        if dist.shape != want:
            raise ParameterError(f"camera model {self.model} needs {want[0]} distortion "
                                 f"coefficients, got {dist.size}")
        if K[0, 1] != 0.0 or not (K[0, 0] > 0 and K[1, 1] > 0):
            raise ParameterError("camera matrix must have positive focal lengths and zero skew")
        w, h = (int(self.size[0]), int(self.size[1]))
        if w < 8 or h < 8:
            raise ParameterError(f"image size {w}x{h} is too small (at least 8x8 pixels)")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "dist", dist)
        object.__setattr__(self, "size", (w, h))

    @classmethod
    def preset(cls, name: str) -> Camera:
        """One of the named cameras :data:`PRESETS` (webcam, hd, wide, fisheye)."""
        if name not in _PRESETS:
            raise ParameterError(f"unknown camera preset {name!r}; "
                                 f"use one of {', '.join(PRESETS)}")
        model, size, fx, fy, cx, cy, dist = _PRESETS[name]
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return cls(model, K, np.array(dist), size)

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
    def from_dict(cls, d: dict[str, Any]) -> Camera:
        """The inverse of :meth:`to_dict`."""
        return cls(str(d["model"]), np.array(d["K"], dtype=np.float64),
                   np.array(d["dist"], dtype=np.float64), (int(d["width"]), int(d["height"])))

    # --- rays ----------------------------------------------------------------------
    def pixel_rays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Viewing ray of every pixel centre and its derivatives (computed once, cached).

        Returns:
            ray: (H, W, 3) float64 direction in the camera frame (any positive scale);
            ray_du, ray_dv: (H, W, 3) float32 derivatives of ``ray`` per pixel step in u and v;
            valid: (H, W) bool, False where the lens model cannot be inverted (beyond a fold of
            the distortion polynomial), so nothing is drawn there.
        """
        if "rays" not in self._cache:
            w, h = self.size
            u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
            u, v = u.ravel(), v.ravel()
            ray = np.empty((h * w, 3))
            # derivatives only scale sub-pixel distances: float32 (1e-7 relative) is plenty
            ray_du, ray_dv = (np.empty((h * w, 3), dtype=np.float32) for _ in range(2))
            valid = np.empty(h * w, dtype=bool)
            # in blocks: temporaries stay in cache, ~3x faster than whole-image arrays
            for i in range(0, h * w, CHUNK):
                sl = slice(i, i + CHUNK)
                ray[sl], ray_du[sl], ray_dv[sl], valid[sl] = rays_from_pixels(self, u[sl], v[sl])
            self._cache["rays"] = (ray.reshape(h, w, 3), ray_du.reshape(h, w, 3),
                                   ray_dv.reshape(h, w, 3), valid.reshape(h, w))
        return self._cache["rays"]  # type: ignore[no-any-return]

    def max_field_radius(self) -> float:
        """Largest undistorted field radius any pixel sees (tan of the angle; radians for
        equidistant). A point beyond it cannot be in the image, even if the (folding)
        distortion polynomial maps it inside."""
        if "rmax" not in self._cache:
            ray, _, _, valid = self.pixel_rays()
            rho = np.hypot(ray[..., 0], ray[..., 1])
            z = ray[..., 2]
            r = np.arctan2(rho, z) if self.model == "equidistant" else rho / z
            self._cache["rmax"] = float(r[valid].max()) if valid.any() else 0.0
        return float(self._cache["rmax"])


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


def distort_normalized(cam: Camera, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, ...]:
    """Pinhole models: undistorted normalized (x, y) -> distorted (xd, yd) and the Jacobian.

    Returns ``xd, yd, dxd_dx, dxd_dy, dyd_dx, dyd_dy`` (arrays shaped like ``x``).
    """
    p1, p2 = cam.dist[2], cam.dist[3]
    r2 = x * x + y * y
    rad, drad = _radial_pinhole(cam.dist, r2)
    xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    cross = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y
    a = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x
    d = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x
    return xd, yd, a, cross, cross, d


def _theta_d(dist: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Equidistant model: theta_d(theta) and d theta_d / d theta."""
    k1, k2, k3, k4 = dist
    t2 = theta * theta
    poly = 1.0 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
    dpoly = 1.0 + t2 * (3.0 * k1 + t2 * (5.0 * k2 + t2 * (7.0 * k3 + t2 * 9.0 * k4)))
    return theta * poly, dpoly


def project_points(cam: Camera, points: np.ndarray, rvec: np.ndarray | None = None,
                   tvec: np.ndarray | None = None) -> np.ndarray:
    """Project 3-D points with the camera's forward model (OpenCV's, to < 1e-9 px).

    Args:
        cam: the camera.
        points: (N, 3) float64, metres; in the camera frame, or in the board frame when
            ``rvec``/``tvec`` (T_cam_board, Rodrigues vector and translation in metres) are given.

    Returns:
        (N, 2) float64 pixels. Points at or behind the camera plane (z <= 0) give NaN.
    """
    P = _as_cam_points(points, rvec, tvec)
    z = P[:, 2]
    front = z > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(front, P[:, 0] / z, np.nan)
        b = np.where(front, P[:, 1] / z, np.nan)
        if cam.model == "equidistant":
            r = np.hypot(a, b)
            theta = np.arctan(r)
            theta_d, _ = _theta_d(cam.dist, theta)
            scale = np.where(r > 1e-8, theta_d / np.where(r > 1e-8, r, 1.0), 1.0)
            xd, yd = a * scale, b * scale
        else:
            xd, yd = distort_normalized(cam, a, b)[:2]
    K = cam.K
    return np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)


def field_radius(cam: Camera, points_cam: np.ndarray) -> np.ndarray:
    """(N,) undistorted field radius of camera-frame points (compare with max_field_radius)."""
    P = np.asarray(points_cam, dtype=np.float64).reshape(-1, 3)
    rho = np.hypot(P[:, 0], P[:, 1])
    if cam.model == "equidistant":
        return np.asarray(np.arctan2(rho, P[:, 2]))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(P[:, 2] > 0, rho / P[:, 2], np.inf)


def _undistort_pinhole(cam: Camera, qx: np.ndarray, qy: np.ndarray,
                       iterations: int = 30) -> tuple[np.ndarray, ...]:
    """Newton's method on distort(x, y) = (qx, qy). Returns x, y, inverse Jacobian, valid."""
    # start from the radial-only inverse at the distorted radius: close enough for Newton
    rad0, _ = _radial_pinhole(cam.dist, qx * qx + qy * qy)
    rad0 = np.where(rad0 > 0.2, rad0, 0.2)
    x, y = qx / rad0, qy / rad0
    for _ in range(iterations):
        xd, yd, a, b, c, d = distort_normalized(cam, x, y)
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
    resid = np.hypot(ex * cam.K[0, 0], ey * cam.K[1, 1])
    valid = (det > 1e-9) & (resid < 1e-7)
    det = np.where(valid, det, 1.0)
    inv = (d / det, -b / det, -c / det, a / det)
    return (x, y, *inv, valid)


def _undistort_equidistant(cam: Camera, qx: np.ndarray,
                           qy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """theta from theta_d = |q| (1-D Newton). Returns theta, d theta / d theta_d, valid."""
    theta_d = np.hypot(qx, qy)
    theta = theta_d.copy()
    for _ in range(30):
        f, df = _theta_d(cam.dist, theta)
        step = (f - theta_d) / np.where(np.abs(df) < 1e-12, 1e-12, df)
        theta -= np.clip(step, -0.2, 0.2)
        if float(np.max(np.abs(f - theta_d))) < 1e-13:
            break
    f, df = _theta_d(cam.dist, theta)
    valid = (df > 1e-9) & (np.abs(f - theta_d) * cam.K[0, 0] < 1e-7) & (theta < np.pi)
    return theta, 1.0 / np.where(df > 1e-12, df, 1e-12), valid


def rays_from_pixels(cam: Camera, u: np.ndarray,
                     v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Viewing rays of pixels (the exact inverse of :func:`project_points`).

    Args:
        u, v: same-shape arrays of pixel coordinates.

    Returns:
        ray, ray_du, ray_dv: (..., 3) ray directions (camera frame, any positive scale) and
        their derivatives per pixel in u and v; valid: (...) bool where the inverse exists.
    """
    K = cam.K
    fx, fy = K[0, 0], K[1, 1]
    qx = (u - K[0, 2]) / fx
    qy = (v - K[1, 2]) / fy
    if cam.model != "equidistant":
        x, y, ia, ib, ic, id_, valid = _undistort_pinhole(cam, qx, qy)
        ray = np.stack([x, y, np.ones_like(x)], axis=-1)
        zero = np.zeros_like(x)
        ray_du = np.stack([ia / fx, ic / fx, zero], axis=-1)
        ray_dv = np.stack([ib / fy, id_ / fy, zero], axis=-1)
        return ray, ray_du, ray_dv, valid
    theta, dtheta, valid = _undistort_equidistant(cam, qx, qy)
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
