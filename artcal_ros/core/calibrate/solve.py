"""The solves behind :func:`artcal_ros.core.calibrate.calibrate` (OpenCV, then weighted LM).

Every solve here is a plain least-squares fit of the points it is given; choosing the
points (outliers, views) is the caller's job. The model primitives live in
:mod:`artcal_ros.core.calibrate.model` and are re-exported here.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from artcal_ros.core.calibrate.lm import bundle_adjust, point_weights
from artcal_ros.core.calibrate.model import (
    DIST_NAMES,
    INTRINSIC_NAMES,
    MODELS,
    Solution,
    ViewPoints,
    estimate_pose,
    free_parameters,
    project,
    project_jacobian,
)
from artcal_ros.core.errors import CalibrationError

__all__ = ["DIST_NAMES", "INTRINSIC_NAMES", "MODELS", "Solution", "ViewPoints",
           "bundle_adjust", "estimate_pose", "free_parameters", "point_weights", "project",
           "project_jacobian", "residuals", "solve"]

_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)


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


def residuals(views: list[ViewPoints], sol: Solution) -> list[np.ndarray]:
    """Per view, (M, 2) float64 pixels: measured minus projected image points."""
    return [v.image_points - project(v.object_points, r, t, sol.camera_matrix,
                                     sol.dist_coeffs, sol.model)
            for v, r, t in zip(views, sol.rvecs, sol.tvecs, strict=True)]
