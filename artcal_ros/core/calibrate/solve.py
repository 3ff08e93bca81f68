"""The solves behind :func:`artcal_ros.core.calibrate.calibrate` (OpenCV, then weighted LM).

Every solve here is a plain least-squares fit of the points it is given; choosing the
points (outliers, views) is the caller's job. The model primitives live in
:mod:`artcal_ros.core.calibrate.model` and are re-exported here.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.calibrate.lm import bundle_adjust, point_weights
from artcal_ros.core.calibrate.model import (
    DIST_NAMES,
    INTRINSIC_NAMES,
    MODELS,
    Solution,
    SolveOptions,
    ViewPoints,
    constrain,
    estimate_pose,
    free_parameters,
    project,
    project_jacobian,
    radial_names,
)
from artcal_ros.core.errors import CalibrationError

__all__ = ["DIST_NAMES", "INTRINSIC_NAMES", "MODELS", "Solution", "SolveOptions", "ViewPoints",
           "bundle_adjust", "estimate_pose", "free_parameters", "point_weights", "project",
           "project_jacobian", "residuals", "solve"]

_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
# A fit that only starts another (the staged fits of the central points) stops sooner: the
# fit after it moves every parameter by far more than this settles.
_START_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 30, 1e-6)
_DEFAULT = SolveOptions()
_FIX_K = (cv2.CALIB_FIX_K1, cv2.CALIB_FIX_K2, cv2.CALIB_FIX_K3, cv2.CALIB_FIX_K4,
          cv2.CALIB_FIX_K5, cv2.CALIB_FIX_K6)
_FISHEYE_FIX_K = (cv2.fisheye.CALIB_FIX_K1, cv2.fisheye.CALIB_FIX_K2, cv2.fisheye.CALIB_FIX_K3,
                  cv2.fisheye.CALIB_FIX_K4)


def opencv_flags(model: str, options: SolveOptions) -> int:
    """``cv2.calibrateCamera`` flags (pinhole models) or ``cv2.fisheye.calibrate`` flags
    (equidistant) that hold what ``options`` holds."""
    n_radial = options.radial_terms(model)
    if model == "equidistant":
        F = cv2.fisheye
        flags = F.CALIB_RECOMPUTE_EXTRINSIC | F.CALIB_FIX_SKEW
        for fix in _FISHEYE_FIX_K[n_radial:]:
            flags |= fix
        if options.fix_principal_point:
            flags |= F.CALIB_FIX_PRINCIPAL_POINT
        return flags  # (no fisheye aspect-ratio flag: the bundle adjustment ties fx = fy)
    flags = cv2.CALIB_FIX_S1_S2_S3_S4 | cv2.CALIB_FIX_TAUX_TAUY
    if model == "rational_polynomial":
        flags |= cv2.CALIB_RATIONAL_MODEL
    for fix in _FIX_K[n_radial:len(radial_names(model))]:
        flags |= fix
    if options.fix_principal_point:
        flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
    if options.fix_aspect_ratio:
        flags |= cv2.CALIB_FIX_ASPECT_RATIO
    if options.zero_tangent_dist:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    return flags


def _initial_fisheye(views: list[ViewPoints], image_size: tuple[int, int],
                     options: SolveOptions = _DEFAULT) -> tuple[np.ndarray, np.ndarray]:
    """Starting intrinsics for the equidistant solve: (K (3, 3), dist (4,)).

    OpenCV's fisheye calibration (its own initialisation) usually gets close; where it
    throws, a pinhole model fitted to the points near the image centre, where the two
    models agree, gives the focal length and principal point. The caller moves the result
    onto the constraints of ``options`` (:func:`constrain`).
    """
    F = cv2.fisheye
    w, h = image_size
    center = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    try:
        _, K, D, _, _ = F.calibrate(
            [v.object_points.reshape(-1, 1, 3) for v in views],
            [v.image_points.reshape(-1, 1, 2) for v in views], image_size, np.eye(3),
            np.zeros((4, 1)), flags=opencv_flags("equidistant", options),
            criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 50, 1e-10))
        K = np.asarray(K, np.float64)
        D = np.asarray(D, np.float64).ravel()
        if np.all(np.isfinite(K)) and np.all(np.isfinite(D)) and K[0, 0] > 0 and K[1, 1] > 0:
            return K, D
    except cv2.error:
        pass
    radius = 0.35 * float(np.hypot(w, h))
    obj, img = [], []
    for v in views:
        near = np.linalg.norm(v.image_points - center, axis=1) < radius
        if near.sum() >= 6:
            obj.append(v.object_points[near].astype(np.float32))
            img.append(v.image_points[near].astype(np.float32))
    if len(obj) < 3:
        obj = [v.object_points.astype(np.float32) for v in views]
        img = [v.image_points.astype(np.float32) for v in views]
    flags = (cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST | cv2.CALIB_FIX_ASPECT_RATIO)
    if options.fix_principal_point:
        flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
    K0 = np.array([[1.0, 0, center[0]], [0, 1.0, center[1]], [0, 0, 1]])
    _, K, _, _, _ = cv2.calibrateCamera(obj, img, (w, h), K0, np.zeros(5), flags=flags)
    return np.asarray(K, dtype=np.float64), np.zeros(4)


def solve(views: list[ViewPoints], image_size: tuple[int, int], model: str, *,
          options: SolveOptions = _DEFAULT, initial: Solution | None = None,
          weighted: bool = False,
          poses: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[Solution,
                                                                     np.ndarray | None]:
    """Fit intrinsics and poses to every point of ``views`` (no outlier handling).

    Without ``initial`` the fit grows outwards from the image centre: first the points
    within half, then three quarters of the half-diagonal, then all of them, each stage
    starting from the last. Strong distortion at the image edges otherwise sends the
    solve into a wrong minimum (OpenCV initialises as if there were no distortion).

    Args:
        views: at least 3 views with at least 4 non-collinear points each.
        image_size: (width, height), pixels.
        model: one of :data:`MODELS`.
        options: what the solve holds fixed (every stage holds it).
        initial: start from these intrinsics.
        weighted: weight each point by 1 / sigma^2 (``ViewPoints.sigma_px``).
        poses: with ``initial``, (rvecs (V, 3), tvecs (V, 3)) T_cam_board of ``views`` to
            start from (a previous solve of nearly the same points). A weighted solve then
            goes straight to the point-weighted LM, which OpenCV's solve would only start.

    Returns:
        (solution, OpenCV's standard deviations of the intrinsics or None).

    Raises:
        CalibrationError: the solver did not converge to a usable camera.
    """
    if initial is not None and poses is not None and (weighted or model == "equidistant"):
        return _refine(views, image_size, model, options, initial, poses, weighted)
    if initial is None:
        w, h = image_size
        center = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
        half_diag = 0.5 * float(np.hypot(w, h))
        # Positions in ``views`` of the views the last stage solved, when it solved the
        # final model itself (its poses can start the final fit).
        solved: list[int] | None = None
        for stage, frac in enumerate((0.5, 0.75)):
            sub, at = [], []
            for k, v in enumerate(views):
                near = np.linalg.norm(v.image_points - center, axis=1) < frac * half_diag
                if near.sum() >= 8:
                    sub.append(v.subset(near))
                    at.append(k)
            if len(sub) < 3 or sum(len(v) for v in sub) == sum(len(v) for v in views):
                continue
            stage_model, stage_options = _stage_model(stage, model, options)
            try:
                initial, _ = _solve_once(sub, image_size, stage_model, options=stage_options,
                                         initial=initial, criteria=_START_CRITERIA)
                solved = at if (stage_model, stage_options) == (model, options) else None
            except CalibrationError:
                initial, solved = None, None
        if initial is not None and solved is not None and weighted and model != "equidistant":
            # OpenCV's solve of every point (unweighted) would only start the weighted LM:
            # start it from the last stage instead, which fitted the same model to each
            # view's central points.
            try:
                return _refine(views, image_size, model, options, initial,
                               _stage_poses(views, solved, initial), weighted)
            except (CalibrationError, cv2.error, np.linalg.LinAlgError):
                pass
    return _solve_once(views, image_size, model, options=options, initial=initial,
                       weighted=weighted)


def _refine(views: list[ViewPoints], image_size: tuple[int, int], model: str,
            options: SolveOptions, initial: Solution, poses: tuple[np.ndarray, np.ndarray],
            weighted: bool) -> tuple[Solution, None]:
    """The bundle adjustment alone, from ``initial``'s intrinsics and the given poses."""
    free = free_parameters(model, options=options)
    K0, D0 = constrain(initial.camera_matrix, initial.dist_coeffs, model, image_size, options)
    K, dist, rv, tv = bundle_adjust(views, K0, D0, model, free=free, weighted=weighted,
                                    poses=poses)
    return _checked(K, dist, rv, tv, model, free), None


def _stage_poses(views: list[ViewPoints], solved: list[int],
                 stage: Solution) -> tuple[np.ndarray, np.ndarray]:
    """(rvecs (V, 3), tvecs (V, 3)) of every view: ``stage``'s pose for the views it
    solved (positions ``solved``), a single-view fit with its intrinsics for the rest."""
    rvecs = np.empty((len(views), 3))
    tvecs = np.empty((len(views), 3))
    have = dict(zip(solved, range(len(solved)), strict=True))
    for k, v in enumerate(views):
        if k in have:
            rvecs[k], tvecs[k] = stage.rvecs[have[k]], stage.tvecs[have[k]]
        else:
            rvecs[k], tvecs[k] = estimate_pose(v, stage.camera_matrix, stage.dist_coeffs,
                                               stage.model)
    return rvecs, tvecs


def _checked(K: np.ndarray, dist: np.ndarray, rv: Any, tv: Any, model: str,
             free: tuple[str, ...]) -> Solution:
    """The solution, or CalibrationError if the solver diverged."""
    K = np.asarray(K, dtype=np.float64)
    dist = np.asarray(dist, dtype=np.float64).ravel()
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(dist)) and K[0, 0] > 0 and K[1, 1] > 0):
        raise CalibrationError(
            f"the {model} solver diverged (non-finite or negative focal length); add views "
            "that tilt the board in different directions and fill the image corners")
    return Solution(K, dist, model, np.asarray(rv, np.float64).reshape(-1, 3),
                    np.asarray(tv, np.float64).reshape(-1, 3), free)


def _stage_model(stage: int, model: str, options: SolveOptions) -> tuple[str, SolveOptions]:
    """The model a stage of the outward-growing solve fits: plumb_bob k1 k2 first; the
    rational model's k4-k6 are freed only on every point (the second stage fits k1-k3).

    On the central points alone the rational model's numerator and denominator can grow a
    common factor that fits them as well and bends the image corners by pixels; the final
    fit, starting from k1-k3 with k4-k6 at zero, stays in the valley of the true lens.
    """
    if model == "equidistant":
        return model, options
    if stage == 0:
        return "plumb_bob", _first_stage(model, options)
    if model == "rational_polynomial":
        return "plumb_bob", replace(options, k_coefficients=min(3, options.radial_terms(model)))
    return model, options


def _first_stage(model: str, options: SolveOptions) -> SolveOptions:
    """The options of a plumb_bob k1 k2 p1 p2 fit that starts a ``model`` solve: the same
    constraints, at most k1 k2."""
    return replace(options, k_coefficients=min(2, options.radial_terms(model)))


def _solve_once(views: list[ViewPoints], image_size: tuple[int, int], model: str, *,
                options: SolveOptions = _DEFAULT, initial: Solution | None = None,
                weighted: bool = False,
                criteria: tuple[int, int, float] = _CRITERIA) -> tuple[Solution,
                                                                       np.ndarray | None]:
    """One fit of intrinsics and poses to every point of ``views``.

    Args:
        views: at least 2 views with at least 4 non-collinear points each.
        image_size: (width, height), pixels.
        model: one of :data:`MODELS`.
        options: what the solve holds fixed.
        initial: start from these intrinsics instead of OpenCV's initialisation (moved
            onto the constraints of ``options`` first).
        weighted: refine with the point-weighted LM after OpenCV's solve.
        criteria: OpenCV's termination criteria (the default: to convergence).

    Returns:
        (solution, OpenCV's standard deviations of the intrinsics or None).

    Raises:
        CalibrationError: the solver did not converge to a usable camera.
    """
    if model not in MODELS:
        raise CalibrationError(f"unknown camera model {model!r}; use one of {', '.join(MODELS)}")
    obj = [v.object_points.astype(np.float64) for v in views]
    img = [v.image_points.astype(np.float64) for v in views]
    free = free_parameters(model, options=options)
    rv: Any
    tv: Any
    try:
        if model == "equidistant":
            if initial is not None:
                K0, D0 = initial.camera_matrix, initial.dist_coeffs
            else:
                K0, D0 = _initial_fisheye(views, image_size, options)
            # The bundle adjustment keeps held parameters where they start.
            K0, D0 = constrain(K0, D0, model, image_size, options)
            K, D, rv, tv = bundle_adjust(views, K0, D0, model, free=free,
                                          weighted=weighted)
            std = None
            dist: np.ndarray = np.asarray(D, dtype=np.float64).ravel()
        else:
            flags = opencv_flags(model, options)
            n = len(DIST_NAMES[model])
            if initial is None and (model == "rational_polynomial"
                                    or options.radial_terms(model) > 2):
                # Higher-order terms free from the start often send OpenCV's solve into a
                # wrong minimum; start them from the k1 k2 p1 p2 fit instead.
                initial, _ = _solve_once(views, image_size, "plumb_bob",
                                         options=_first_stage(model, options),
                                         criteria=_START_CRITERIA)
            if initial is not None:
                # With a guess OpenCV holds fixed terms at their given values: give it the
                # held ones (principal point, fx = fy, zeros).
                flags |= cv2.CALIB_USE_INTRINSIC_GUESS
                K0, d0 = constrain(initial.camera_matrix, initial.dist_coeffs, model,
                                   image_size, options)
                D0 = np.zeros(14)
                D0[: len(d0)] = d0
            else:
                # Without one it starts from fx / fy = 1 and cx, cy at ((w-1)/2, (h-1)/2).
                K0, D0 = np.eye(3), np.zeros(14)
            _, K, D, rv, tv, std_i, _, _ = cv2.calibrateCameraExtended(
                [o.astype(np.float32) for o in obj], [i.astype(np.float32) for i in img],
                image_size, K0, D0, flags=flags, criteria=criteria)
            dist = np.asarray(D, dtype=np.float64).ravel()[:n]
            std_all = np.asarray(std_i, dtype=np.float64).ravel()
            std = np.concatenate([std_all[:4], std_all[4:4 + n]])
    except cv2.error as e:
        raise CalibrationError(
            f"the {model} solver failed ({e.err.strip() if hasattr(e, 'err') else e}); "
            "check that the board parameters (board.cols, board.rows and its lengths) match "
            "the printed board, and add views that tilt the "
            "board in different directions") from None
    K = np.asarray(K, dtype=np.float64)
    if weighted and model != "equidistant" and np.all(np.isfinite(K)):
        # OpenCV weighs every point alike; refine with each point's measured uncertainty.
        K, dist, rv, tv = bundle_adjust(
            views, K, dist, model, free=free, weighted=True,
            poses=(np.asarray(rv, np.float64).reshape(-1, 3),
                   np.asarray(tv, np.float64).reshape(-1, 3)))
        std = None
    return _checked(K, dist, rv, tv, model, free), std


def residuals(views: list[ViewPoints], sol: Solution) -> list[np.ndarray]:
    """Per view, (M, 2) float64 pixels: measured minus projected image points."""
    return [v.image_points - project(v.object_points, r, t, sol.camera_matrix,
                                     sol.dist_coeffs, sol.model)
            for v, r, t in zip(views, sol.rvecs, sol.tvecs, strict=True)]
