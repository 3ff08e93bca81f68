"""Camera models for calibration: correspondences, solutions, projection, single-view poses.

Three models, named as in sensor_msgs/CameraInfo:

- ``plumb_bob``: pinhole + Brown-Conrady distortion, OpenCV order (k1, k2, p1, p2, k3);
  k3 is held at zero unless asked for (the paper's model has k1, k2, p1, p2).
- ``rational_polynomial``: (k1, k2, p1, p2, k3, k4, k5, k6).
- ``equidistant``: OpenCV's fisheye model, (k1, k2, k3, k4).

Skew is always zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.errors import CalibrationError

MODELS = ("plumb_bob", "rational_polynomial", "equidistant")

# Names of the intrinsic parameters in the order their standard deviations are reported.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")
DIST_NAMES = {
    "plumb_bob": ("k1", "k2", "p1", "p2", "k3"),
    "rational_polynomial": ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"),
    "equidistant": ("k1", "k2", "k3", "k4"),
}

@dataclass(frozen=True)
class ViewPoints:
    """The correspondences of one view.

    Attributes:
        index: position of the view in the caller's list of detections.
        source: where the image came from (for reports).
        object_points: (M, 3) float64, metres, board frame (z = 0).
        image_points: (M, 2) float64, pixels.
        marker_ids: (M,) int64, the marker each point belongs to.
        sharpness: focus measure of the image (NaN if unknown).
        marker_corners_px: (M, 4, 2) float64 pixels, for marker centres: the corners they
            were measured from (so the centres can be corrected for distortion); else None.
        sigma_px: (M,) float64, the detector's 1-sigma error of each point, pixels (NaN
            where unknown), or None.
    """

    index: int
    source: str
    object_points: np.ndarray
    image_points: np.ndarray
    marker_ids: np.ndarray
    sharpness: float = float("nan")
    marker_corners_px: np.ndarray | None = None
    sigma_px: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.image_points)

    def subset(self, mask: np.ndarray) -> ViewPoints:
        """Only the points ``mask`` selects."""
        corners = None if self.marker_corners_px is None else self.marker_corners_px[mask]
        sigma = None if self.sigma_px is None else self.sigma_px[mask]
        return ViewPoints(self.index, self.source, self.object_points[mask],
                          self.image_points[mask], self.marker_ids[mask], self.sharpness,
                          corners, sigma)

    def with_image_points(self, image_points: np.ndarray) -> ViewPoints:
        """The same view with other image points (M, 2), pixels."""
        return ViewPoints(self.index, self.source, self.object_points, image_points,
                          self.marker_ids, self.sharpness, self.marker_corners_px,
                          self.sigma_px)


@dataclass(frozen=True)
class Solution:
    """Intrinsics and per-view poses from one solve.

    Attributes:
        camera_matrix: (3, 3) float64, pixels.
        dist_coeffs: (n,) float64, OpenCV order for ``model``.
        model: one of :data:`MODELS`.
        rvecs, tvecs: (V, 3) float64, T_cam_board of each view (Rodrigues, metres).
        free: names of the parameters that were estimated (others held fixed).
    """

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    model: str
    rvecs: np.ndarray
    tvecs: np.ndarray
    free: tuple[str, ...]


def free_parameters(model: str, k3: bool) -> tuple[str, ...]:
    """Names of the parameters a solve of ``model`` estimates."""
    names = DIST_NAMES[model]
    if model == "plumb_bob" and not k3:
        names = names[:4]
    return INTRINSIC_NAMES + names


def project(object_points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
            camera_matrix: np.ndarray, dist_coeffs: np.ndarray, model: str) -> np.ndarray:
    """Project board points into the image.

    Args:
        object_points: (M, 3) float64, metres, board frame.
        rvec, tvec: (3,) T_cam_board.
        camera_matrix: (3, 3); dist_coeffs: (n,) for ``model``.

    Returns:
        (M, 2) float64, pixels.
    """
    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    if model == "equidistant":
        img, _ = cv2.fisheye.projectPoints(obj, np.asarray(rvec, np.float64).reshape(3, 1),
                                           np.asarray(tvec, np.float64).reshape(3, 1),
                                           camera_matrix, np.asarray(dist_coeffs).reshape(4, 1))
    else:
        img, _ = cv2.projectPoints(obj, np.asarray(rvec, np.float64), np.asarray(tvec, np.float64),
                                   camera_matrix, np.asarray(dist_coeffs, np.float64))
    return img.reshape(-1, 2)


def project_jacobian(object_points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
                     camera_matrix: np.ndarray, dist_coeffs: np.ndarray,
                     model: str) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives of the projection of one view's points.

    Returns:
        (intrinsic (2M, 4 + n): d pixel / d (fx, fy, cx, cy, dist...),
         extrinsic (2M, 6): d pixel / d (rvec, tvec)); rows alternate x, y per point.
    """
    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    if model == "equidistant":
        _, J = cv2.fisheye.projectPoints(obj, np.asarray(rvec, np.float64).reshape(3, 1),
                                         np.asarray(tvec, np.float64).reshape(3, 1),
                                         camera_matrix, np.asarray(dist_coeffs).reshape(4, 1))
        # fisheye columns: fx fy cx cy k1..k4 rvec(3) tvec(3) alpha
        return J[:, 0:8], J[:, 8:14]
    _, J = cv2.projectPoints(obj, np.asarray(rvec, np.float64), np.asarray(tvec, np.float64),
                             camera_matrix, np.asarray(dist_coeffs, np.float64))
    # pinhole columns: rvec(3) tvec(3) fx fy cx cy dist(n)
    return J[:, 6:], J[:, 0:6]


def estimate_pose(view: ViewPoints, camera_matrix: np.ndarray, dist_coeffs: np.ndarray,
                  model: str) -> tuple[np.ndarray, np.ndarray]:
    """T_cam_board of one view with the intrinsics held fixed: (rvec (3,), tvec (3,)).

    Both poses a planar target admits (IPPE) are refined in the distorted image and the
    one that fits better is kept.
    """
    if model == "equidistant":
        und = cv2.fisheye.undistortPoints(view.image_points.reshape(-1, 1, 2), camera_matrix,
                                          np.asarray(dist_coeffs).reshape(4, 1))
    else:
        und = cv2.undistortPointsIter(view.image_points.reshape(-1, 1, 2), camera_matrix,
                                      np.asarray(dist_coeffs, np.float64), np.eye(3), np.eye(3),
                                      (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 50,
                                       1e-12))
    n, cand_r, cand_t, _ = cv2.solvePnPGeneric(view.object_points, und.reshape(-1, 2),
                                               np.eye(3), np.zeros(5), flags=cv2.SOLVEPNP_IPPE)
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for k in range(n):
        r, t = _refine_pose(view, camera_matrix, dist_coeffs, model,
                            np.asarray(cand_r[k]).ravel(), np.asarray(cand_t[k]).ravel())
        err = float(np.sum((view.image_points - project(view.object_points, r, t,
                                                        camera_matrix, dist_coeffs,
                                                        model)) ** 2))
        if np.isfinite(err) and (best is None or err < best[0]):
            best = (err, r, t)
    if best is None:
        raise CalibrationError(f"no pose found for view {view.source or view.index}")
    return best[1], best[2]


def _refine_pose(view: ViewPoints, K: np.ndarray, dist: np.ndarray, model: str,
                 rvec: np.ndarray, tvec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gauss-Newton on the 6 pose parameters, steps halved until the error drops."""
    x = np.concatenate([rvec, tvec]).astype(np.float64)

    def sse(y: np.ndarray) -> float:
        e = float(np.sum((view.image_points - project(view.object_points, y[:3], y[3:], K,
                                                      dist, model)) ** 2))
        return e if np.isfinite(e) else np.inf

    current = sse(x)
    for _ in range(20):
        r = (view.image_points - project(view.object_points, x[:3], x[3:], K, dist, model))
        _, J = project_jacobian(view.object_points, x[:3], x[3:], K, dist, model)
        step, *_ = np.linalg.lstsq(J, r.ravel(), rcond=None)
        for _half in range(10):
            trial = sse(x + step)
            if trial <= current:
                break
            step = step / 2.0
        else:
            break
        x = x + step
        improvement = current - trial
        current = trial
        if improvement <= 1e-14 * max(current, 1e-30):
            break
    return x[:3].copy(), x[3:].copy()
