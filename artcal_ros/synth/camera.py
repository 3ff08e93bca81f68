"""The renderer's cameras: named presets and the per-pixel ray table drawing needs.

A :class:`Camera` is a :class:`~artcal_ros.core.camera.CameraModel` (the one camera model of
the package, with OpenCV's forward projection written out in numpy and its exact inverse), so
the renderer, its ground truth and a calibration result are compared as equals.
"""

from __future__ import annotations

import numpy as np

from artcal_ros.core.camera import MODELS, CameraModel
from artcal_ros.core.errors import ParameterError

__all__ = ["CHUNK", "MODELS", "PRESETS", "Camera", "field_radius", "project_points",
           "rays_from_pixels"]

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
    # a low-cost 320x240 camera (the paper's smallest): a short lens with marked barrel
    "lowcost": ("plumb_bob", (320, 240), 290.0, 291.2, 158.6, 122.3,
                (-0.25, 0.09, 0.0010, 0.0007, 0.0)),
    # an equidistant fisheye (cv2.fisheye model), about 170 degrees across the diagonal
    "fisheye": ("equidistant", (1024, 768), 350.0, 350.4, 514.1, 381.6,
                (0.04, -0.012, 0.003, -0.0004)),
}
PRESETS = tuple(_PRESETS)

# pixels per block in vectorised per-pixel work (keeps numpy temporaries in cache)
CHUNK = 65536


class Camera(CameraModel):
    """A :class:`CameraModel` the renderer draws through (same fields and validation), with
    the named presets and a cached viewing ray of every pixel."""

    @classmethod
    def preset(cls, name: str) -> Camera:
        """One of the named cameras :data:`PRESETS` (webcam, hd, wide, lowcost, fisheye)."""
        if name not in _PRESETS:
            raise ParameterError(f"unknown camera preset {name!r}; "
                                 f"use one of {', '.join(PRESETS)}")
        model, size, fx, fy, cx, cy, dist = _PRESETS[name]
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return cls(model, K, np.array(dist), size)

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
            # in blocks: temporaries stay in cache, several times faster than whole-image arrays
            for i in range(0, h * w, CHUNK):
                sl = slice(i, i + CHUNK)
                ray[sl], ray_du[sl], ray_dv[sl], valid[sl] = self.rays(u[sl], v[sl])
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


def project_points(cam: CameraModel, points: np.ndarray, rvec: np.ndarray | None = None,
                   tvec: np.ndarray | None = None) -> np.ndarray:
    """(N, 2) pixels of 3-D points; see :meth:`CameraModel.project`."""
    return cam.project(points, rvec, tvec)


def field_radius(cam: CameraModel, points_cam: np.ndarray) -> np.ndarray:
    """(N,) field radius of camera-frame points; see :meth:`CameraModel.field_radius`."""
    return cam.field_radius(points_cam)


def rays_from_pixels(cam: CameraModel, u: np.ndarray,
                     v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Viewing rays of pixels and their derivatives; see :meth:`CameraModel.rays`."""
    return cam.rays(u, v)
