"""The result of a rig solve: each camera's part as a :class:`CalibrationResult`, the pairs'
extrinsics and rectification, and the corresponding points of a pair (the same board point
in the same frame) for the epipolar error."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.model import DIST_NAMES, TIED_FOCAL, Solution
from artcal_ros.core.calibrate.quality import parameter_effect_px
from artcal_ros.core.calibrate.rectify import rectify_pair
from artcal_ros.core.calibrate.result import CalibrationResult, DroppedView
from artcal_ros.core.calibrate.rig_result import RigPair, RigResult
from artcal_ros.core.calibrate.rig_solve import (
    RigObservation,
    RigSolution,
    compose,
    pair_std_devs,
    pair_transform,
)
from artcal_ros.core.calibrate.rig_start import shared_frame_counts
from artcal_ros.core.calibrate.views import coverage_cells, feature_term
from artcal_ros.core.live.view_geometry import COVERAGE_GRID, MIN_COVERAGE

PARAM_EFFECT_WARN_PX = 0.5  # as the single-camera pipeline: a weak parameter moves this much
WEAK_PAIR_FRAMES = 5  # a connecting pair with fewer shared frames gets a warning


def _named_std_devs(free: tuple[str, ...], std: np.ndarray) -> dict[str, float]:
    out: dict[str, float] = {}
    for name, s in zip(free, std, strict=True):
        for n in (("fx", "fy") if name == TIED_FOCAL else (name,)):
            out[n] = float(s)
    return out


def camera_result(k: int, size: tuple[int, int], points: str, sol: RigSolution,
                  obs: Sequence[RigObservation], frames: Sequence[int],
                  single: CalibrationResult | None, dropped: Sequence[DroppedView],
                  outliers: Sequence[np.ndarray], board: Board) -> CalibrationResult:
    """Camera ``k``'s calibration from the joint solve.

    The intrinsics, residuals, per-frame poses (T_cam_board) and standard deviations are
    the joint solve's; the hold-out error is the camera's own calibration's (NaN for
    given intrinsics).
    """
    cam = sol.cameras[k]
    mine = [(o, r) for o, r in zip(obs, sol.residuals, strict=True) if o.camera == k]
    res = [r for _, r in mine]
    allr = np.concatenate(res) if res else np.zeros((0, 2))
    norms = np.linalg.norm(allr, axis=1)
    rms = float(np.sqrt(np.mean(norms ** 2))) if len(norms) else float("nan")
    std = float(np.sqrt(0.5 * (np.var(allr[:, 0]) + np.var(allr[:, 1])))) if len(norms) \
        else float("nan")
    poses = np.array([compose(sol.poses[o.frame], sol.extrinsics[k]) for o, _ in mine]
                     ).reshape(-1, 6)
    cov = sol.covariance[sol.intrinsic_slices[k], sol.intrinsic_slices[k]]
    std_dev = np.sqrt(np.maximum(np.diag(cov), 0.0))
    as_solution = Solution(cam.K, cam.dist, cam.model, poses[:, :3], poses[:, 3:], cam.free)
    views = [o.view for o, _ in mine]
    warnings: list[str] = []
    if cam.free:
        effects, unc_rms, unc_max = parameter_effect_px(as_solution, size, cov)
        for name, s, e in zip(cam.free, std_dev, effects, strict=True):
            if not np.isfinite(e) or e > PARAM_EFFECT_WARN_PX:
                warnings.append(f"{name} is poorly determined (1-sigma {s:.3g}, moves the image "
                                f"by up to {e:.2f} px); add views tilted more steeply and with "
                                f"{feature_term(board)} in the image corners")
    else:
        unc_rms = unc_max = 0.0
    coverage = float(np.mean(coverage_cells(views, size).any(axis=0))) if views else 0.0
    if coverage < MIN_COVERAGE:
        warnings.append(f"points cover only {100 * coverage:.0f}% of the image "
                        f"({COVERAGE_GRID[0]}x{COVERAGE_GRID[1]} grid); add views with "
                        f"{feature_term(board)} near the edges and corners")
    dist = np.zeros(len(DIST_NAMES[cam.model]))
    dist[:len(cam.dist)] = cam.dist[:len(dist)]
    return CalibrationResult(
        camera_matrix=cam.K.copy(), dist_coeffs=dist, model=cam.model, image_size=size,
        points=points, reprojection_rms_px=rms, reprojection_std_px=std,
        reprojection_max_px=float(norms.max()) if len(norms) else float("nan"),
        holdout_rms_px=single.holdout_rms_px if single is not None else float("nan"),
        views_used=tuple(frames[o.frame] for o, _ in mine),
        views_dropped=tuple(sorted(dropped, key=lambda d: d.view_index)),
        points_dropped=int(sum(len(x) for x in outliers)),
        per_view_rms_px=np.array([float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))
                                  for r in res]),
        rvecs=poses[:, :3].copy(), tvecs=poses[:, 3:].copy(),
        std_devs=_named_std_devs(cam.free, std_dev),
        projection_uncertainty_rms_px=unc_rms, projection_uncertainty_max_px=unc_max,
        coverage=coverage, warnings=tuple(warnings),
        points_px=np.concatenate([v.image_points for v in views]) if views else allr,
        residuals_px=allr,
        point_view=(np.concatenate([np.full(len(o.view), frames[o.frame]) for o, _ in mine])
                    if mine else np.zeros(0, np.int64)),
        outliers_px=np.concatenate(list(outliers)) if outliers else np.zeros((0, 2)),
        free=cam.free, covariance=cov)


def _keys(object_points: np.ndarray) -> list[tuple[float, float, float]]:
    # Both cameras' board points come from the same board description: equal to the bit.
    return [tuple(p) for p in np.round(np.asarray(object_points, np.float64), 9).tolist()]


def epipolar_correspondences(obs: Sequence[RigObservation], a: int,
                             b: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2), (N, 2) pixels: the image points of cameras ``a`` and ``b`` of every board
    point both measure in the same frame, row by row."""
    by_frame: dict[int, dict[int, RigObservation]] = {}
    for o in obs:
        by_frame.setdefault(o.frame, {})[o.camera] = o
    pa: list[np.ndarray] = []
    pb: list[np.ndarray] = []
    for seen in by_frame.values():
        if a not in seen or b not in seen:
            continue
        va, vb = seen[a].view, seen[b].view
        at = {key: i for i, key in enumerate(_keys(vb.object_points))}
        for i, key in enumerate(_keys(va.object_points)):
            j = at.get(key)
            if j is not None:
                pa.append(va.image_points[i])
                pb.append(vb.image_points[j])
    if not pa:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.array(pa), np.array(pb)


def rig_result(names: tuple[str, ...], sizes: dict[str, tuple[int, int]], points: str,
               board: Board, fixed: Mapping[str, object],
               single: Mapping[str, CalibrationResult | None], sol: RigSolution,
               obs: list[RigObservation], frames: list[int],
               dropped: dict[str, list[DroppedView]], outliers: dict[str, list[np.ndarray]],
               points_dropped: int, tree: Sequence[tuple[str, str]],
               elapsed_s: float) -> RigResult:
    """The :class:`RigResult` of a finished joint solve: each camera's result, every ordered
    pair's extrinsics with their uncertainty, the rectification of consecutive pairs."""
    cameras = {n: camera_result(k, sizes[n], points, sol, obs, frames, single[n],
                                dropped[n], outliers[n], board)
               for k, n in enumerate(names)}
    seen = {n: {frames[o.frame] for o in obs if o.camera == k} for k, n in enumerate(names)}
    shared = shared_frame_counts(names, seen)
    extrinsics: dict[tuple[str, str], tuple[np.ndarray, np.ndarray]] = {}
    pairs: dict[tuple[str, str], RigPair] = {}
    for a_k, a in enumerate(names):
        for b_k, b in enumerate(names):
            if a == b:
                continue
            R, t = pair_transform(sol.extrinsics, a_k, b_k)
            rot_std, t_std, base_std = pair_std_devs(sol, a_k, b_k)
            extrinsics[a, b] = (R, t)
            pairs[a, b] = RigPair(a, b, R, t, float(np.linalg.norm(t)), base_std, rot_std,
                                  t_std, len(seen[a] & seen[b]))
    rectification = {}
    for k in range(len(names) - 1):
        a, b = names[k], names[k + 1]
        pa, pb = epipolar_correspondences(obs, k, k + 1)
        R, t = extrinsics[a, b]
        rectification[a, b] = rectify_pair(a, b, cameras[a].camera, cameras[b].camera, R, t,
                                           pa, pb)
    warnings = [f"cameras {a} and {b} share only {shared.get((a, b), shared.get((b, a), 0))} "
                f"frames: hold the board where both see part of it in a few more"
                for a, b in tree if len(seen[a] & seen[b]) < WEAK_PAIR_FRAMES]
    res_all = np.concatenate([r for r in sol.residuals])
    all_dropped = sorted({(d.view_index, d.source, f"{n}: {d.reason}")
                          for n in names for d in dropped[n]})
    return RigResult(
        names=names, cameras=cameras, extrinsics=extrinsics, pairs=pairs, shared_frames=shared,
        rectification=rectification, frames_used=tuple(frames),
        frames_dropped=tuple(DroppedView(*d) for d in all_dropped),
        board_rvecs=sol.poses[:, :3].copy(), board_tvecs=sol.poses[:, 3:].copy(),
        reprojection_rms_px=float(np.sqrt(np.mean(np.sum(res_all ** 2, axis=1)))),
        points_dropped=points_dropped, fixed_intrinsics=len(fixed) == len(names),
        solve_time_s=elapsed_s, warnings=tuple(warnings))
