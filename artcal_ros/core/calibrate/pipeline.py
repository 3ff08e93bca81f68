"""Camera calibration from marker detections: the solve, outliers, uncertainty, selection.

::

    result = calibrate([dets, ...], board, image_size=(w, h), model="plumb_bob",
                       points="centers")
    result.camera_matrix, result.dist_coeffs, result.reprojection_rms_px

The pipeline: correspondences per view (marker centres or corners; partial views are
fine) -> unusable views set aside with the reason -> at most ``max_views`` diverse views
kept -> degeneracy checks -> OpenCV solve -> outlier views, then outlier points, dropped
and the solve repeated -> with the detector's sigmas, the weights re-scaled to the
residuals (each view's sigmas by the factor its residuals show, then Huber's weight per
point; :func:`~artcal_ros.core.calibrate.lm.reweighted`) and the solve repeated -> sanity
checks (a camera that cannot be right is an error, never a result) -> uncertainty of every
parameter, k-fold hold-out error and warnings where the data cannot pin a parameter down.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.lm import reweighted
from artcal_ros.core.calibrate.model import TIED_FOCAL
from artcal_ros.core.calibrate.quality import (
    cross_validate,
    fold_radius_px,
    intrinsic_covariance,
    parameter_effect_px,
    solution_camera,
)
from artcal_ros.core.calibrate.result import CalibrationResult, DroppedView
from artcal_ros.core.calibrate.solve import (
    DIST_NAMES,
    MODELS,
    Solution,
    SolveOptions,
    ViewPoints,
    residuals,
    solve,
)
from artcal_ros.core.calibrate.views import (
    POINTS_MODES,
    GeometryCache,
    coverage_cells,
    feature_term,
    layout_outliers,
    lens_corrected_centers,
    select_views,
    view_points,
    view_problem,
    views_problem,
)
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import CalibrationError
from artcal_ros.core.live.view_geometry import COVERAGE_GRID, MIN_COVERAGE

__all__ = ["MODELS", "POINTS_MODES", "CalibrationResult", "DroppedView", "calibrate",
           "select_views"]

OUTLIER_SIGMAS = 5.0  # a point further than this many robust sigmas from its projection
OUTLIER_FLOOR_PX = 0.5  # ... and at least this far is an outlier
VIEW_OUTLIER_FACTOR = 3.0  # a view whose RMS exceeds this many times the median view's
VIEW_OUTLIER_FRACTION = 0.25  # or with more than this share of outlier points is dropped
REWEIGHT_ROUNDS = 2  # weighted solves re-scale the sigmas to the residuals this often
MAX_RMS_PX = 1.0  # above this (x image diagonal / 1000, if larger) the board description
# or the lens model is wrong: good detections fit to a few tenths of a pixel


def max_rms_px(image_size: tuple[int, int]) -> float:
    """The largest RMS reprojection error accepted for an image of this size, pixels."""
    return max(MAX_RMS_PX, 1e-3 * float(np.hypot(*image_size)))
PARAM_EFFECT_WARN_PX = 0.5  # a parameter whose 1-sigma moves the image this much is weak


def _stats(res: Sequence[np.ndarray]) -> tuple[float, float, float]:
    r = np.concatenate([np.asarray(x).reshape(-1, 2) for x in res])
    norms = np.linalg.norm(r, axis=1)
    rms = float(np.sqrt(np.mean(norms ** 2)))
    std = float(np.sqrt(0.5 * (np.var(r[:, 0]) + np.var(r[:, 1]))))
    return rms, std, float(norms.max())


def _reject(views: list[ViewPoints], res: list[np.ndarray], board: Board, size: tuple[int, int],
            dropped: list[DroppedView], outliers: list[np.ndarray]) -> tuple[list[ViewPoints],
                                                                           int]:
    """One round of outlier rejection: whole views first, then single points.

    Returns:
        (the views kept, the number of points removed from them).
    """
    norms = [np.linalg.norm(r, axis=1) for r in res]
    alln = np.concatenate(norms)
    # Residual lengths of 2-D Gaussian noise follow a Rayleigh law: median = 1.1774 sigma.
    sigma = float(np.median(alln)) / 1.1774
    thr = max(OUTLIER_SIGMAS * sigma, OUTLIER_FLOOR_PX)
    # A view's RMS over its inlier points: one bad point must not condemn a good view.
    view_rms = np.array([float(np.sqrt(np.mean(n[n <= thr] ** 2))) if (n <= thr).any()
                         else float(np.sqrt(np.mean(n ** 2))) for n in norms])
    frac = np.array([float(np.mean(n > thr)) for n in norms])
    med = float(np.median(view_rms))
    if med > max_rms_px(size):
        raise CalibrationError(
            f"the {len(views)} views cannot be fitted together (median view RMS {med:.1f} px): "
            f"the board parameters ({board.size_parameters}) or the camera_model are wrong, "
            "or the solve started "
            "badly; add views tilted 20-45 degrees in different directions")
    bad_view = (frac > VIEW_OUTLIER_FRACTION) | (
        view_rms > max(VIEW_OUTLIER_FACTOR * med, OUTLIER_FLOOR_PX))
    if bad_view.any():
        # Drop only the worst tenth per round: a view that merely suffered from another
        # view's pull on the solve comes back below the bar once that one is gone.
        worst = np.argsort(-np.where(bad_view, view_rms, -np.inf))[:max(1, len(views) // 10)]
        bad_view = np.zeros(len(views), dtype=bool)
        bad_view[worst] = True
        bad_view &= (frac > VIEW_OUTLIER_FRACTION) | (
            view_rms > max(VIEW_OUTLIER_FACTOR * med, OUTLIER_FLOOR_PX))
    if bad_view.any() and (~bad_view).sum() >= 3:
        kept = []
        for v, b, e, f in zip(views, bad_view, view_rms, frac, strict=True):
            if b:
                dropped.append(DroppedView(v.index, v.source,
                                           f"outlier view: RMS {e:.2f} px vs median {med:.2f} "
                                           f"px, {100 * f:.0f}% of its points off by > "
                                           f"{thr:.2f} px"))
            else:
                kept.append(v)
        return kept, 0
    kept = []
    removed = 0
    for v, n in zip(views, norms, strict=True):
        good = n <= thr
        if good.all():
            kept.append(v)
            continue
        outliers.append(v.image_points[~good])
        sub = _still_usable(v, good, board, dropped, "outlier points")
        if sub is None:
            continue
        removed += int((~good).sum())
        kept.append(sub)
    return kept, removed


def _still_usable(view: ViewPoints, good: np.ndarray, board: Board, dropped: list[DroppedView],
                  what: str) -> ViewPoints | None:
    """The view's ``good`` points, or None (the view recorded as dropped, saying why) when
    they no longer make a usable view."""
    sub = view.subset(good)
    problem = view_problem(sub, board)
    if problem is None:
        return sub
    dropped.append(DroppedView(view.index, view.source, f"after removing {what}: {problem}"))
    return None


def _layout_check(views: list[ViewPoints], board: Board, dropped: list[DroppedView],
                  outliers: list[np.ndarray]) -> tuple[list[ViewPoints], int]:
    """Drop markers that disagree with the board layout, and views where many do.

    A single misidentified view (another board, wrong ids) would otherwise pull the first
    solve so far that no view fits any more. Returns (views kept, points removed).
    """
    kept: list[ViewPoints] = []
    removed = 0
    for v in views:
        bad = layout_outliers(v, board)
        if not bad.any():
            kept.append(v)
            continue
        if bad.mean() > VIEW_OUTLIER_FRACTION:
            dropped.append(DroppedView(
                v.index, v.source, f"markers do not match the board layout ({int(bad.sum())} "
                f"of {len(bad)} out of place): check board.cols and board.rows, or the "
                "view shows another board"))
            continue
        ids = np.unique(v.marker_ids)
        good = ~np.isin(v.marker_ids, ids[bad])
        sub = _still_usable(v, good, board, dropped, "misplaced markers")
        if sub is None:
            continue
        outliers.append(v.image_points[~good])
        removed += int((~good).sum())
        kept.append(sub)
    return kept, removed


def calibrate(detections: Sequence[Detections], board: Board, *, image_size: tuple[int, int],
              model: str = "plumb_bob", points: str = "corners", max_views: int = 40,
              k_coefficients: int = 0, fix_principal_point: bool = False,
              fix_aspect_ratio: bool = False, zero_tangent_dist: bool = False,
              k3: bool = False, cross_validation_folds: int = 5, weighted: bool = True,
              accept_weak: bool = False,
              progress: Callable[[str], None] | None = None) -> CalibrationResult:
    """Calibrate a camera from the markers found in several images.

    Args:
        detections: one :class:`Detections` per image (empty ones are fine).
        board: the board the markers belong to.
        image_size: (width, height) of the images, pixels.
        model: ``plumb_bob`` | ``rational_polynomial`` | ``equidistant``.
        points: ``centers`` (one point per marker) or ``corners`` (four per marker).
        max_views: at most this many views are solved (diverse ones are chosen).
        k_coefficients: radial terms solved, k1..kN (the ``calibrate.k_coefficients``
            parameter): 0 the model's default (k1 k2 for plumb_bob, all for the others);
            up to 3 for plumb_bob, 6 for rational_polynomial, 4 for equidistant. The terms
            not solved are zero.
        fix_principal_point: hold cx, cy at the image centre ((w - 1) / 2, (h - 1) / 2).
        fix_aspect_ratio: solve one focal length, fx = fy.
        zero_tangent_dist: hold p1 = p2 = 0 (plumb_bob, rational_polynomial).
        k3: deprecated, the same as ``k_coefficients=3`` for plumb_bob.
        cross_validation_folds: folds of the hold-out error (0 to skip it).
        weighted: weight each point by the detector's 1/sigma^2 where it gives sigmas
            (``corner_sigma_px``/``center_sigma_px``), re-scaled to the residuals (per
            view, and Huber's weight per point); views without them weigh alike.
        accept_weak: solve a set the view checks refuse (too few views, one tilt) when a
            solve is possible at all; the result's ``weak_reason`` says why it would have
            been refused and its uncertainty how much that costs.
        progress: called with a short message at each stage.

    Returns:
        The calibration with its quality figures.

    Raises:
        CalibrationError: the views cannot support a solve (the message says what views
            to add; with ``accept_weak`` only when no view is usable or the solve fails) or
            the solve did not give a camera that can be right.
        ParameterError: ``k_coefficients`` is out of range for the model.
    """
    start = time.monotonic()
    say = progress or (lambda _msg: None)
    if model not in MODELS:
        raise CalibrationError(f"camera model {model!r} is not one of {', '.join(MODELS)}")
    if k3 and model == "plumb_bob" and k_coefficients == 0:
        k_coefficients = 3
    options = SolveOptions(int(k_coefficients), bool(fix_principal_point),
                           bool(fix_aspect_ratio), bool(zero_tangent_dist))
    options.check(model)
    if points not in POINTS_MODES:
        raise CalibrationError(f"points {points!r} is not one of {', '.join(POINTS_MODES)}")
    w, h = int(image_size[0]), int(image_size[1])
    if w <= 0 or h <= 0:
        raise CalibrationError(f"image size {w}x{h} is not valid")
    size = (w, h)

    dropped: list[DroppedView] = []
    usable: list[ViewPoints] = []
    for i, det in enumerate(detections):
        v = view_points(det, board, points, i)
        problem = view_problem(v, board)
        if problem is None:
            usable.append(v)
        else:
            dropped.append(DroppedView(i, det.source, problem))
    # Each view's rough geometry (guessed camera) once, for the checks and the selection.
    cache = GeometryCache()
    weak: list[str] = []

    def check_views(views: list[ViewPoints]) -> None:
        problem = views_problem(views, size, [(d.view_index, d.reason) for d in dropped],
                                board=board, cache=cache)
        if problem is None:
            return
        if not accept_weak or not views:
            raise CalibrationError(problem)
        if not weak:
            weak.append(problem)

    check_views(usable)
    if len(usable) > max_views:
        say(f"selecting {max_views} of {len(usable)} views")
        keep = set(select_views(usable, size, max_views, cache=cache))
        for k, v in enumerate(usable):
            if k not in keep:
                dropped.append(DroppedView(v.index, v.source, "not selected (similar views kept)"))
        usable = [v for k, v in enumerate(usable) if k in keep]
    outliers: list[np.ndarray] = []
    usable, points_dropped = _layout_check(usable, board, dropped, outliers)
    check_views(usable)

    say(f"solving {model} from {len(usable)} views")
    views = usable
    weighted = weighted and any(
        v.sigma_px is not None and np.isfinite(v.sigma_px).any() for v in views)
    try:
        sol, _ = solve(views, size, model, options=options, weighted=weighted)
    except CalibrationError as e:
        if not weak:
            raise
        raise CalibrationError(f"{weak[0]}; a solve anyway (--accept-weak) failed too: "
                               f"{e}") from None
    if points == "centers":
        # Re-measure the centres through the fitted lens, then solve again (twice: the
        # second pass moves them by far less than their noise).
        for _pass in range(2):
            views = [lens_corrected_centers(v, solution_camera(sol, size))
                     for v in views]
            sol, _ = solve(views, size, model, options=options, initial=sol,
                           weighted=weighted, poses=(sol.rvecs, sol.tvecs))
    for _round in range(8):
        res = residuals(views, sol)
        kept, removed = _reject(views, res, board, size, dropped, outliers)
        if len(kept) == len(views) and removed == 0:
            break
        points_dropped += removed
        check_views(kept)
        previous, views = views, kept
        say(f"re-solving without outliers ({len(views)} views, {points_dropped} points dropped)")
        sol, _ = solve(views, size, model, options=options, initial=sol, weighted=weighted,
                       poses=_poses_of(views, previous, sol))
    if weighted:
        # The detector's sigmas re-scaled to the residuals (per view, then Huber per
        # point), measured each round against the detector's own sigmas.
        measured = views
        for _round in range(REWEIGHT_ROUNDS):
            views = reweighted(measured, residuals(views, sol))
            sol, _ = solve(views, size, model, options=options, initial=sol, weighted=True,
                           poses=(sol.rvecs, sol.tvecs))
    res = residuals(views, sol)
    rms, std, worst = _stats(res)
    _sanity(sol, views, size, rms, board)

    say("estimating uncertainty")
    cov, _sigma = intrinsic_covariance(views, sol, res, weighted=weighted, by_marker=True)
    std_dev = np.sqrt(np.maximum(np.diag(cov), 0.0))
    effects, unc_rms, unc_max = parameter_effect_px(sol, size, cov)
    holdout = float("nan")
    if cross_validation_folds > 1:
        say(f"{cross_validation_folds}-fold cross-validation")
        holdout = cross_validate(views, sol, folds=cross_validation_folds, weighted=weighted)
    coverage = float(np.mean(coverage_cells(views, size).any(axis=0)))
    warnings = _warnings(sol, size, views, std_dev, effects, rms, holdout, coverage,
                         feature_term(board))
    per_view = np.array([float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))) for r in res])
    return CalibrationResult(
        camera_matrix=sol.camera_matrix, dist_coeffs=_full_dist(sol), model=model,
        image_size=size, points=points, reprojection_rms_px=rms, reprojection_std_px=std,
        reprojection_max_px=worst, holdout_rms_px=holdout,
        views_used=tuple(v.index for v in views),
        views_dropped=tuple(sorted(dropped, key=lambda d: d.view_index)),
        points_dropped=points_dropped, per_view_rms_px=per_view, rvecs=sol.rvecs,
        tvecs=sol.tvecs, std_devs=_named_std_devs(sol.free, std_dev), free=sol.free,
        projection_uncertainty_rms_px=unc_rms, projection_uncertainty_max_px=unc_max,
        coverage=coverage, warnings=tuple(warnings),
        points_px=np.concatenate([v.image_points for v in views]),
        residuals_px=np.concatenate(res),
        point_view=np.concatenate([np.full(len(v), v.index) for v in views]),
        outliers_px=(np.concatenate(outliers) if outliers else np.zeros((0, 2))),
        solve_time_s=time.monotonic() - start, weak_reason=weak[0] if weak else "",
        covariance=cov)


def _poses_of(views: Sequence[ViewPoints], solved: Sequence[ViewPoints],
              sol: Solution) -> tuple[np.ndarray, np.ndarray]:
    """(rvecs (V, 3), tvecs (V, 3)) of ``views`` in ``sol``, the solve of ``solved`` (a
    superset of them: the same views, some with fewer points)."""
    at = {v.index: k for k, v in enumerate(solved)}
    rows = [at[v.index] for v in views]
    return sol.rvecs[rows], sol.tvecs[rows]


def _named_std_devs(free: tuple[str, ...], std_dev: np.ndarray) -> dict[str, float]:
    """1-sigma by parameter name; a tied focal length (fx = fy) is listed as both."""
    out: dict[str, float] = {}
    for name, s in zip(free, std_dev, strict=True):
        for n in (("fx", "fy") if name == TIED_FOCAL else (name,)):
            out[n] = float(s)
    return out


def _full_dist(sol: Solution) -> np.ndarray:
    """Distortion with every coefficient of the model (fixed ones as zeros)."""
    out = np.zeros(len(DIST_NAMES[sol.model]))
    out[: len(sol.dist_coeffs)] = sol.dist_coeffs
    return out


def _sanity(sol: Solution, views: Sequence[ViewPoints], size: tuple[int, int],
            rms: float, board: Board) -> None:
    """Raise CalibrationError for a camera that cannot be right."""
    w, h = size
    K = sol.camera_matrix
    limit = max_rms_px(size)
    if rms > limit:
        raise CalibrationError(
            f"the best {sol.model} fit leaves {rms:.2f} px RMS reprojection error (> "
            f"{limit:.1f} px): check the board parameters ({board.size_parameters}) and the "
            "camera_model")
    if not (0 <= K[0, 2] <= w and 0 <= K[1, 2] <= h):
        raise CalibrationError(
            f"the solve put the principal point at ({K[0, 2]:.0f}, {K[1, 2]:.0f}), outside the "
            f"{w}x{h} image: a bad initialisation; add views tilted in different directions")
    if not 0.5 < K[0, 0] / K[1, 1] < 2.0:
        raise CalibrationError(
            f"the solve gave fx/fy = {K[0, 0] / K[1, 1]:.2f}: a bad initialisation; add views "
            "tilted in different directions")
    cam = solution_camera(sol, size)
    fold = fold_radius_px(cam)
    reach = max(float(np.max(np.linalg.norm(v.image_points - K[:2, 2], axis=1)))
                for v in views)
    if fold < reach:
        raise CalibrationError(
            f"the fitted {sol.model} distortion folds back {fold:.0f} px from the principal "
            f"point, inside the observed points (out to {reach:.0f} px): the model cannot "
            "describe this lens or the solve started badly; try another camera_model")


def _warnings(sol: Solution, size: tuple[int, int], views: Sequence[ViewPoints],
              std_dev: np.ndarray, effects: np.ndarray, rms: float, holdout: float,
              coverage: float, term: str) -> list[str]:
    """Say what the data cannot pin down, and what to add (``term``: what the board's
    features are called, :func:`feature_term`)."""
    out = []
    for name, s, e in zip(sol.free, std_dev, effects, strict=True):
        if not np.isfinite(e) or e > PARAM_EFFECT_WARN_PX:
            shown = "fx = fy" if name == TIED_FOCAL else name
            out.append(f"{shown} is poorly determined (1-sigma {s:.3g}, moves the image by up to "
                       f"{e:.2f} px); add views tilted more steeply and with {term} in the "
                       "image corners")
    # The node's readiness judges by the same grid and threshold (core.live.view_geometry): a
    # collection it calls ready does not get this warning.
    if coverage < MIN_COVERAGE:
        out.append(f"points cover only {100 * coverage:.0f}% of the image "
                   f"({COVERAGE_GRID[0]}x{COVERAGE_GRID[1]} grid); "
                   f"distortion outside them is extrapolated: add views with {term} near the "
                   "edges and corners")
    if np.isfinite(holdout) and holdout > 1.5 * rms + 0.05:
        out.append(f"hold-out error {holdout:.3f} px is much larger than the fit's {rms:.3f} "
                   "px: the views do not constrain the model well; add more varied views")
    elif np.isinf(holdout):
        out.append("cross-validation failed: some subsets of the views cannot be solved; "
                   "add more varied views")
    w, h = size
    K = sol.camera_matrix
    corner = max(float(np.hypot(x - K[0, 2], y - K[1, 2])) for x in (0, w) for y in (0, h))
    fold = fold_radius_px(solution_camera(sol, size))
    if fold < corner:
        out.append(f"the fitted distortion folds back {fold:.0f} px from the principal point, "
                   "inside the image: do not trust the image corners; add views covering them")
    if len(views) < 10:
        out.append(f"only {len(views)} views; 15-20 are recommended")
    return out
