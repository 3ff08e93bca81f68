"""The camera models and the OpenCV solves behind :func:`artcal_ros.core.calibrate.calibrate`.

Three models, named as in sensor_msgs/CameraInfo:

- ``plumb_bob``: pinhole + Brown-Conrady distortion, OpenCV order (k1, k2, p1, p2, k3);
  k3 is held at zero unless asked for (the paper's model has k1, k2, p1, p2).
- ``rational_polynomial``: (k1, k2, p1, p2, k3, k4, k5, k6).
- ``equidistant``: OpenCV's fisheye model, (k1, k2, k3, k4).

Skew is always held at zero. Every solve here is a plain least-squares fit of
the points it is given; choosing the points (outliers, views) is the caller's job.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

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

_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)


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


def _initial_fisheye(views: list[ViewPoints],
                     image_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Starting intrinsics for the equidistant solve: (K (3, 3), dist (4,)).

    OpenCV's fisheye calibration (its own initialisation) usually gets close; where it
    throws, a pinhole model fitted to the points near the image centre, where the two
    models agree, gives the focal length and principal point.
    """
    F = cv2.fisheye
    try:
        _, K, D, _, _ = F.calibrate(
            [v.object_points.reshape(-1, 1, 3) for v in views],
            [v.image_points.reshape(-1, 1, 2) for v in views], image_size, np.eye(3),
            np.zeros((4, 1)), flags=F.CALIB_RECOMPUTE_EXTRINSIC | F.CALIB_FIX_SKEW,
            criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 50, 1e-10))
        K = np.asarray(K, np.float64)
        D = np.asarray(D, np.float64).ravel()
        if np.all(np.isfinite(K)) and np.all(np.isfinite(D)) and K[0, 0] > 0 and K[1, 1] > 0:
            return K, D
    except cv2.error:
        pass
    w, h = image_size
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    radius = 0.35 * float(np.hypot(w, h))
    obj, img = [], []
    for v in views:
        near = np.linalg.norm(v.image_points - centre, axis=1) < radius
        if near.sum() >= 6:
            obj.append(v.object_points[near].astype(np.float32))
            img.append(v.image_points[near].astype(np.float32))
    if len(obj) < 3:
        obj = [v.object_points.astype(np.float32) for v in views]
        img = [v.image_points.astype(np.float32) for v in views]
    flags = (cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_ASPECT_RATIO)
    K0 = np.array([[1.0, 0, centre[0]], [0, 1.0, centre[1]], [0, 0, 1]])
    _, K, _, _, _ = cv2.calibrateCamera(obj, img, (w, h), K0, np.zeros(5), flags=flags)
    return np.asarray(K, dtype=np.float64), np.zeros(4)


def solve(views: list[ViewPoints], image_size: tuple[int, int], model: str, *, k3: bool = False,
          initial: Solution | None = None,
          weighted: bool = False) -> tuple[Solution, np.ndarray | None]:
    """Fit intrinsics and poses to every point of ``views`` (no outlier handling).

    Without ``initial`` the fit grows outwards from the image centre: first the points
    within half, then three quarters of the half-diagonal, then all of them, each stage
    starting from the last. Strong distortion at the image edges otherwise sends the
    solve into a wrong minimum (OpenCV initialises as if there were no distortion).

    Args:
        views: at least 3 views with at least 4 non-collinear points each.
        image_size: (width, height), pixels.
        model: one of :data:`MODELS`.
        k3: also estimate k3 (``plumb_bob`` only).
        initial: start from these intrinsics.
        weighted: weight each point by 1 / sigma^2 (``ViewPoints.sigma_px``).

    Returns:
        (solution, OpenCV's standard deviations of the intrinsics or None).

    Raises:
        CalibrationError: the solver did not converge to a usable camera.
    """
    if initial is None:
        w, h = image_size
        centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
        half_diag = 0.5 * float(np.hypot(w, h))
        for stage, frac in enumerate((0.5, 0.75)):
            sub = []
            for v in views:
                near = np.linalg.norm(v.image_points - centre, axis=1) < frac * half_diag
                if near.sum() >= 8:
                    sub.append(v.subset(near))
            if len(sub) < 3 or sum(len(v) for v in sub) == sum(len(v) for v in views):
                continue
            stage_model, stage_k3 = ("plumb_bob", False) if (
                stage == 0 and model != "equidistant") else (model, k3)
            try:
                initial, _ = _solve_once(sub, image_size, stage_model, k3=stage_k3,
                                         initial=initial)
            except CalibrationError:
                initial = None
    return _solve_once(views, image_size, model, k3=k3, initial=initial, weighted=weighted)


def _solve_once(views: list[ViewPoints], image_size: tuple[int, int], model: str, *,
                k3: bool = False, initial: Solution | None = None,
                weighted: bool = False) -> tuple[Solution, np.ndarray | None]:
    """One fit of intrinsics and poses to every point of ``views``.

    Args:
        views: at least 2 views with at least 4 non-collinear points each.
        image_size: (width, height), pixels.
        model: one of :data:`MODELS`.
        k3: also estimate k3 (``plumb_bob`` only).
        initial: start from these intrinsics instead of OpenCV's initialisation.

    Returns:
        (solution, OpenCV's standard deviations of the intrinsics or None).

    Raises:
        CalibrationError: the solver did not converge to a usable camera.
    """
    if model not in MODELS:
        raise CalibrationError(f"unknown camera model {model!r}; use one of {', '.join(MODELS)}")
    obj = [v.object_points.astype(np.float64) for v in views]
    img = [v.image_points.astype(np.float64) for v in views]
    free = free_parameters(model, k3)
    rv: Any
    tv: Any
    try:
        if model == "equidistant":
            if initial is not None:
                K0, D0 = initial.camera_matrix.copy(), initial.dist_coeffs.copy()
            else:
                K0, D0 = _initial_fisheye(views, image_size)
            K, D, rv, tv = bundle_adjust(views, K0, D0, model, free=free,
                                          weighted=weighted)
            std = None
            dist: np.ndarray = np.asarray(D, dtype=np.float64).ravel()
        else:
            flags = cv2.CALIB_FIX_S1_S2_S3_S4 | cv2.CALIB_FIX_TAUX_TAUY
            n = 5
            if model == "rational_polynomial":
                flags |= cv2.CALIB_RATIONAL_MODEL
                n = 8
            elif not k3:
                flags |= cv2.CALIB_FIX_K3
            if initial is None and (model == "rational_polynomial" or k3):
                # Higher-order terms free from the start often send OpenCV's solve into a
                # wrong minimum; start them from the k1 k2 p1 p2 fit instead.
                initial, _ = _solve_once(views, image_size, "plumb_bob", k3=False)
            if initial is not None:
                flags |= cv2.CALIB_USE_INTRINSIC_GUESS
                K0 = initial.camera_matrix.copy()
                D0 = np.zeros(14)
                D0[: len(initial.dist_coeffs)] = initial.dist_coeffs
            else:
                K0, D0 = np.eye(3), np.zeros(14)
            _, K, D, rv, tv, std_i, _, _ = cv2.calibrateCameraExtended(
                [o.astype(np.float32) for o in obj], [i.astype(np.float32) for i in img],
                image_size, K0, D0, flags=flags, criteria=_CRITERIA)
            dist = np.asarray(D, dtype=np.float64).ravel()[:n]
            std_all = np.asarray(std_i, dtype=np.float64).ravel()
            std = np.concatenate([std_all[:4], std_all[4:4 + n]])
    except cv2.error as e:
        raise CalibrationError(
            f"the {model} solver failed ({e.err.strip() if hasattr(e, 'err') else e}); "
            "check that the board parameters (board.cols, board.rows, board.marker_length, "
            "board.marker_separation) match the printed board, and add views that tilt the "
            "board in different directions") from None
    K = np.asarray(K, dtype=np.float64)
    if weighted and model != "equidistant" and np.all(np.isfinite(K)):
        # OpenCV weighs every point alike; refine with each point's measured uncertainty.
        K, dist, rv, tv = bundle_adjust(
            views, K, dist, model, free=free, weighted=True,
            poses=(np.asarray(rv, np.float64).reshape(-1, 3),
                   np.asarray(tv, np.float64).reshape(-1, 3)))
        std = None
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(dist)) and K[0, 0] > 0 and K[1, 1] > 0):
        raise CalibrationError(
            f"the {model} solver diverged (non-finite or negative focal length); add views "
            "that tilt the board in different directions and fill the image corners")
    sol = Solution(K, dist, model, np.asarray(rv, np.float64).reshape(-1, 3),
                   np.asarray(tv, np.float64).reshape(-1, 3), free)
    return sol, std


def point_weights(view: ViewPoints) -> np.ndarray:
    """(M,) least-squares weight of each point: 1 / sigma^2, sigma floored at 0.01 px.

    Points of unknown sigma get the view's median weight (1 where no sigma is known).
    """
    if view.sigma_px is None:
        return np.ones(len(view))
    sigma = np.maximum(np.asarray(view.sigma_px, dtype=np.float64), 0.01)
    known = np.isfinite(sigma)
    if not known.any():
        return np.ones(len(view))
    w = np.where(known, 1.0 / np.where(known, sigma, 1.0) ** 2, np.nan)
    return np.where(known, w, float(np.median(w[known])))


def bundle_adjust(views: list[ViewPoints], K0: np.ndarray, D0: np.ndarray, model: str,
                   *, free: tuple[str, ...], weighted: bool = False,
                   poses: tuple[np.ndarray, np.ndarray] | None = None,
                   max_iterations: int = 100) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray]:
    """Levenberg-Marquardt over the free intrinsics and every view's pose.

    Used for the equidistant model (OpenCV's fisheye calibration re-initialises the
    poses at every iteration and fails outright when the distortion wanders) and to
    weight points by their measured uncertainty (OpenCV's solvers cannot). Only steps
    that lower the error are accepted. Poses are eliminated by a Schur complement, so a
    step costs one small dense solve however many views there are.

    Args:
        free: names of the intrinsics to estimate (others stay at K0, D0).
        weighted: weight each point by :func:`point_weights`.
        poses: (rvecs (V, 3), tvecs (V, 3)) to start from; estimated if None.

    Returns:
        (K (3, 3), dist (n,), rvecs (V, 3), tvecs (V, 3)).
    """
    if poses is None:
        est = [estimate_pose(v, K0, D0, model) for v in views]
        x_ex = np.array([np.concatenate([r, t]) for r, t in est])
    else:
        x_ex = np.hstack([np.asarray(poses[0]), np.asarray(poses[1])]).astype(np.float64)
    x_all = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], *D0], dtype=np.float64)
    names = INTRINSIC_NAMES + DIST_NAMES[model][:len(D0)]
    cols = np.array([names.index(n) for n in free if n in names])
    x_in = x_all[cols]
    sqrt_w = [np.repeat(np.sqrt(point_weights(v) if weighted else np.ones(len(v))), 2)
              for v in views]

    def unpack(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        full = x_all.copy()
        full[cols] = xi
        K = np.array([[full[0], 0.0, full[2]], [0.0, full[1], full[3]], [0.0, 0.0, 1.0]])
        return K, full[4:].copy()

    def cost(xi: np.ndarray, xe: np.ndarray) -> float:
        K, D = unpack(xi)
        total = 0.0
        for v, pose, sw in zip(views, xe, sqrt_w, strict=True):
            r = (v.image_points - project(v.object_points, pose[:3], pose[3:], K, D,
                                          model)).ravel() * sw
            total += float(np.sum(r ** 2))
        return total if np.isfinite(total) else np.inf

    lam = 1e-3
    current = cost(x_in, x_ex)
    p = len(x_in)
    for _ in range(max_iterations):
        done = False
        K, D = unpack(x_in)
        U = np.zeros((p, p))
        g = np.zeros(p)
        blocks = []
        for v, pose, sw in zip(views, x_ex, sqrt_w, strict=True):
            A, B = project_jacobian(v.object_points, pose[:3], pose[3:], K, D, model)
            A = A[:, cols] * sw[:, None]
            B = B * sw[:, None]
            r = (v.image_points - project(v.object_points, pose[:3], pose[3:], K, D,
                                          model)).ravel() * sw
            U += A.T @ A
            g += A.T @ r
            blocks.append((A.T @ B, B.T @ B, B.T @ r))
        improved = False
        while lam < 1e10:
            S = U + lam * np.diag(np.diag(U))
            rhs = g.copy()
            inv_v = []
            for W, V, gb in blocks:
                Vi = np.linalg.inv(V + lam * np.diag(np.diag(V)))
                inv_v.append(Vi)
                S -= W @ Vi @ W.T
                rhs -= W @ Vi @ gb
            try:
                d_in = np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            d_ex = np.array([Vi @ (gb - W.T @ d_in)
                             for (W, _, gb), Vi in zip(blocks, inv_v, strict=True)])
            trial = cost(x_in + d_in, x_ex + d_ex)
            if trial < current:
                x_in, x_ex = x_in + d_in, x_ex + d_ex
                done = current - trial < 1e-12 * max(current, 1e-30)
                current = trial
                lam = max(lam / 3.0, 1e-9)
                improved = True
                break
            lam *= 4.0
        if not improved or done:
            break
    K, D = unpack(x_in)
    return K, D, x_ex[:, :3].copy(), x_ex[:, 3:].copy()


def residuals(views: list[ViewPoints], sol: Solution) -> list[np.ndarray]:
    """Per view, (M, 2) float64 pixels: measured minus projected image points."""
    return [v.image_points - project(v.object_points, r, t, sol.camera_matrix,
                                     sol.dist_coeffs, sol.model)
            for v, r, t in zip(views, sol.rvecs, sol.tvecs, strict=True)]


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
