"""Rig calibration: several cameras of fixed relative pose, solved together.

::

    rig = calibrate_rig({"left": [dets, ...], "right": [dets, ...]}, board,
                        image_sizes={"left": (w, h), "right": (w, h)})
    R, t = rig.extrinsics["left", "right"]   # x_right = R @ x_left + t, metres

The pipeline: each camera calibrated alone (:func:`~.pipeline.calibrate`, or its given
intrinsics) -> each camera's board pose in every frame where it measures the board ->
connectivity through shared frames (a camera cut off is an error that says what to show)
-> extrinsics started from the robust median of the relative poses (a camera's frame whose
board pose disagrees with the rest of its pair's is left out as not simultaneous) -> joint
bundle adjustment of every intrinsic, extrinsic and frame pose (:mod:`.rig_solve`) ->
outlier points and observations dropped, weights re-scaled to the residuals, solved again ->
covariance of the extrinsics, rectification of consecutive pairs (:mod:`.rectify`) -> the
verdict (:mod:`.rig_verdict`): a pair whose joint fit is far worse than its cameras' own is
refused.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.lm import reweighted
from artcal_ros.core.calibrate.model import (
    MODELS,
    SolveOptions,
    ViewPoints,
    estimate_pose,
    free_parameters,
    refine_pose,
)
from artcal_ros.core.calibrate.pipeline import calibrate
from artcal_ros.core.calibrate.result import CalibrationResult, DroppedView
from artcal_ros.core.calibrate.rig_cameras import rig_result
from artcal_ros.core.calibrate.rig_result import Pair, RigResult
from artcal_ros.core.calibrate.rig_solve import (
    RigCamera,
    RigObservation,
    RigSolution,
    pair_transform,
    rig_bundle_adjust,
    rig_residuals,
)
from artcal_ros.core.calibrate.rig_start import (
    connectivity_problem,
    initial_board_poses,
    initial_extrinsics,
    shared_frame_counts,
    spanning_tree,
)
from artcal_ros.core.calibrate.rig_verdict import (
    EXCESS_REFUSE_FACTOR,
    EXCESS_REFUSE_PX,
    check_pairs,
    observation_excess,
    refusal,
    warnings_of,
)
from artcal_ros.core.calibrate.views import POINTS_MODES, lens_corrected_centers, view_points
from artcal_ros.core.camera import CameraModel
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import CalibrationError, ParameterError

MIN_RIG_FEATURES = 4  # markers (or points) of one camera in one frame that join the solve
OUTLIER_SIGMAS = 5.0  # as the single-camera pipeline: a point this many robust sigmas off
OUTLIER_FLOOR_PX = 0.5  # ... and at least this far is an outlier
OBSERVATION_OUTLIER_FACTOR = 3.0  # an observation whose RMS is this many times the median's
REWEIGHT_ROUNDS = 2
APART_FACTOR = 5.0  # a frame this many times the pair's median disagreement at the start


def _observation_problem(view: ViewPoints, board: Board) -> str | None:
    """Why one camera's points in one frame cannot join the rig solve, or None."""
    ids = np.unique(view.marker_ids)
    what = "points" if board.has_points else "markers"
    if len(ids) < MIN_RIG_FEATURES:
        return f"{len(ids)} {what}, needs at least {MIN_RIG_FEATURES}"
    rc = board.feature_cells(ids)
    if len(np.unique(rc[:, 0])) < 2 or len(np.unique(rc[:, 1])) < 2:
        return f"its {what} lie on one line of the board"
    return None


def _check_inputs(detections: Mapping[str, Sequence[Detections | None]],
                  image_sizes: Mapping[str, tuple[int, int]],
                  model: str | Mapping[str, str], points: str,
                  fixed: Mapping[str, tuple[np.ndarray, np.ndarray]]) -> dict[str, str]:
    """Refuse bad arguments with a message naming them; returns each camera's model."""
    names = list(detections)
    if len(names) < 2:
        raise ParameterError(f"a rig needs two or more cameras; got {len(names)} ({names})")
    counts = {n: len(detections[n]) for n in names}
    if len(set(counts.values())) != 1:
        listed = ", ".join(f"{n} {c}" for n, c in counts.items())
        raise CalibrationError(f"the cameras have different numbers of frames ({listed}); "
                               "a rig frame is one image of every camera at the same instant")
    for what, given in (("image_sizes", image_sizes), ("fixed_intrinsics", fixed)):
        unknown = [n for n in given if n not in counts]
        if unknown:
            raise ParameterError(f"{what} names camera(s) {', '.join(unknown)} not among the "
                                 f"rig's cameras ({', '.join(names)})")
    missing = [n for n in names if n not in image_sizes]
    if missing:
        raise ParameterError(f"image_sizes lacks camera(s) {', '.join(missing)}")
    models = {n: model if isinstance(model, str) else model.get(n, "") for n in names}
    for n, m in models.items():
        if m not in MODELS:
            raise ParameterError(f"camera {n}: camera model {m!r} is not one of "
                                 f"{', '.join(MODELS)}")
    if points not in POINTS_MODES:
        raise ParameterError(f"points {points!r} is not one of {', '.join(POINTS_MODES)}")
    return models


def _fixed_camera(name: str, model: str, size: tuple[int, int],
                  given: tuple[np.ndarray, np.ndarray]) -> CameraModel:
    K, dist = given
    try:
        return CameraModel(model, np.asarray(K, np.float64), np.asarray(dist, np.float64),
                           size)
    except ParameterError as e:
        raise ParameterError(f"fixed_intrinsics of camera {name}: {e}") from None


def _camera_views(dets: Sequence[Detections], board: Board, points: str,
                  dropped: list[DroppedView]) -> dict[int, ViewPoints]:
    """Frame index -> one camera's points there, where enough to join the solve."""
    out: dict[int, ViewPoints] = {}
    for f, det in enumerate(dets):
        if len(det) == 0 and len(det.point_ids) == 0:
            continue
        v = view_points(det, board, points, f)
        problem = _observation_problem(v, board)
        if problem is None:
            out[f] = v
        else:
            dropped.append(DroppedView(f, det.source, problem))
    return out


def _camera_poses(views: dict[int, ViewPoints], cam: CameraModel, points: str,
                  dropped: list[DroppedView]) -> tuple[dict[int, ViewPoints],
                                                       dict[int, tuple[np.ndarray, np.ndarray]]]:
    """The views (centres re-measured through the lens) and their T_cam_board, by frame;
    views without a pose are dropped."""
    kept: dict[int, ViewPoints] = {}
    poses: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for f, v in views.items():
        if points == "centers":
            v = lens_corrected_centers(v, cam)
        try:
            poses[f] = _in_front(v, cam, estimate_pose(v, cam.K, cam.dist, cam.model))
            kept[f] = v
        except CalibrationError:
            dropped.append(DroppedView(f, v.source, "no board pose found"))
    return kept, poses


def _in_front(view: ViewPoints, cam: CameraModel,
              pose: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The pose with the board in front of the camera. A fisheye's projection divides by
    the depth, so a board mirrored through the optical centre (R diag(-1, -1, 1), -t) gives
    the same image; alone that is harmless, but composed with the extrinsics it is not."""
    R = cv2.Rodrigues(np.asarray(pose[0], np.float64))[0]
    if float(np.mean(view.object_points @ R[2] + pose[1][2])) > 0:
        return pose
    r = cv2.Rodrigues(R @ np.diag([-1.0, -1.0, 1.0]))[0].ravel()
    r, t, err = refine_pose(view, cam.K, cam.dist, cam.model, r, -np.asarray(pose[1]))
    return (r, t) if np.isfinite(err) else pose


def _check_connected(names: Sequence[str],
                     views: Mapping[str, Mapping[int, ViewPoints]]) -> dict[Pair, int]:
    """Every pair's shared frames; CalibrationError when a camera is cut off."""
    shared = shared_frame_counts(names, {n: set(views[n]) for n in names})
    problem = connectivity_problem(names, shared)
    if problem is not None:
        raise CalibrationError(problem)
    return shared


def _select_frames(frames_seen: dict[int, int], max_frames: int) -> list[int]:
    """The frames to solve: those most cameras see first, evenly spread over the
    recording within each count; at most ``max_frames``."""
    chosen: list[int] = []
    for count in sorted(set(frames_seen.values()), reverse=True):
        group = sorted(f for f, c in frames_seen.items() if c == count)
        room = max_frames - len(chosen)
        if room <= 0:
            break
        if len(group) > room:
            group = [group[int(k)] for k in np.linspace(0, len(group) - 1, room).round()]
        chosen += group
    return sorted(set(chosen))


def _reject(obs: list[RigObservation], res: Sequence[np.ndarray], board: Board,
            names: Sequence[str], dropped: dict[str, list[DroppedView]],
            outliers: dict[str, list[np.ndarray]]) -> tuple[list[RigObservation], int]:
    """One round of outlier rejection: whole observations, then single points."""
    norms = [np.linalg.norm(r, axis=1) for r in res]
    sigma = float(np.median(np.concatenate(norms))) / 1.1774  # Rayleigh median
    thr = max(OUTLIER_SIGMAS * sigma, OUTLIER_FLOOR_PX)
    rms = np.array([float(np.sqrt(np.mean(n[n <= thr] ** 2))) if (n <= thr).any()
                    else float(np.sqrt(np.mean(n ** 2))) for n in norms])
    med = float(np.median(rms))
    bad = rms > max(OBSERVATION_OUTLIER_FACTOR * med, OUTLIER_FLOOR_PX)
    kept: list[RigObservation] = []
    removed = 0
    for o, n, b, e in zip(obs, norms, bad, rms, strict=True):
        name = names[o.camera]
        if b and bad.sum() <= max(1, len(obs) // 10):
            dropped[name].append(DroppedView(o.view.index, o.view.source,
                                             f"outlier view: RMS {e:.2f} px vs median "
                                             f"{med:.2f} px"))
            continue
        good = n <= thr
        if good.all():
            kept.append(o)
            continue
        sub = o.view.subset(good)
        outliers[name].append(o.view.image_points[~good])
        problem = _observation_problem(sub, board)
        if problem is not None:
            dropped[name].append(DroppedView(o.view.index, o.view.source,
                                             f"after removing outlier points: {problem}"))
            continue
        removed += int((~good).sum())
        kept.append(RigObservation(o.camera, o.frame, sub))
    return kept, removed


def _renumber(obs: list[RigObservation], poses: np.ndarray,
              frames: list[int]) -> tuple[list[RigObservation], np.ndarray, list[int]]:
    """Drop frames no observation refers to any more."""
    used = sorted({o.frame for o in obs})
    at = {f: k for k, f in enumerate(used)}
    return ([RigObservation(o.camera, at[o.frame], o.view) for o in obs], poses[used],
            [frames[f] for f in used])


def calibrate_rig(detections: Mapping[str, Sequence[Detections | None]], board: Board, *,
                  image_sizes: Mapping[str, tuple[int, int]],
                  model: str | Mapping[str, str] = "plumb_bob", points: str = "corners",
                  fixed_intrinsics: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
                  k_coefficients: int = 0, fix_principal_point: bool = False,
                  fix_aspect_ratio: bool = False, zero_tangent_dist: bool = False,
                  max_frames: int = 60, weighted: bool = True,
                  progress: Callable[[str], None] | None = None) -> RigResult:
    """Calibrate a rig of cameras from synchronised detections.

    Args:
        detections: camera name -> one entry per rig frame (the same index is the same
            instant in every camera; None or an empty Detections where the camera saw
            nothing). The first camera is the reference.
        board: the board all cameras see.
        image_sizes: camera name -> (width, height), pixels.
        model: the lens model of every camera, or camera name -> model.
        points: ``centers`` or ``corners`` (as :func:`~.pipeline.calibrate`).
        fixed_intrinsics: camera name -> (K (3, 3), dist (n,)) held fixed (the
            ``calibrate.fix_intrinsics`` parameter gives every camera's); the others are
            calibrated.
        k_coefficients, fix_principal_point, fix_aspect_ratio, zero_tangent_dist: what each
            calibrated camera holds (as :func:`~.pipeline.calibrate`).
        max_frames: at most this many rig frames in the joint solve (those most cameras
            see first).
        weighted: weight points by the detector's sigmas, re-scaled to the residuals.
        progress: called with a short message at each stage.

    Raises:
        CalibrationError: a camera cannot be calibrated, or is not connected to the
            others through shared frames (the message names it, the shared frames of
            each pair and what to show), or a pair's cameras do not fit one board pose
            per frame (images of different instants: the message gives the figures).
        ParameterError: a bad argument (named).
    """
    start = time.monotonic()
    say = progress or (lambda _msg: None)
    fixed = dict(fixed_intrinsics or {})
    models = _check_inputs(detections, image_sizes, model, points, fixed)
    names = tuple(detections)
    sizes = {n: (int(image_sizes[n][0]), int(image_sizes[n][1])) for n in names}
    options = SolveOptions(int(k_coefficients), bool(fix_principal_point),
                           bool(fix_aspect_ratio), bool(zero_tangent_dist))
    n_frames = len(detections[names[0]])
    dets = {n: [d if d is not None else Detections.empty(sizes[n]) for d in detections[n]]
            for n in names}

    # Step 1. Each camera's points in every frame; are the cameras connected at all?
    dropped: dict[str, list[DroppedView]] = {n: [] for n in names}
    views = {n: _camera_views(dets[n], board, points, dropped[n]) for n in names}
    _check_connected(names, views)

    # Step 2. Each camera alone: its intrinsics (or the given ones), its board poses.
    single: dict[str, CalibrationResult | None] = {}
    cams: dict[str, CameraModel] = {}
    poses: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    for n in names:
        if n in fixed:
            cams[n], single[n] = _fixed_camera(n, models[n], sizes[n], fixed[n]), None
        else:
            say(f"calibrating camera {n} alone")
            try:
                res = calibrate(dets[n], board, image_size=sizes[n], model=models[n],
                                points=points, k_coefficients=options.k_coefficients,
                                fix_principal_point=options.fix_principal_point,
                                fix_aspect_ratio=options.fix_aspect_ratio,
                                zero_tangent_dist=options.zero_tangent_dist, weighted=weighted)
            except CalibrationError as e:
                raise CalibrationError(f"camera {n}: {e}") from None
            cams[n], single[n] = res.camera, res
            for d in res.views_dropped:  # its own outliers would pull the joint solve too
                if d.view_index in views[n] and not d.reason.startswith("not selected"):
                    del views[n][d.view_index]
                    dropped[n].append(DroppedView(d.view_index, d.source,
                                                  f"left out by its own calibration: {d.reason}"))
        views[n], poses[n] = _camera_poses(views[n], cams[n], points, dropped[n])

    # Step 3. The frames to solve and the start.
    shared = _check_connected(names, views)
    tree = spanning_tree(names, shared)
    seen_by = {f: sum(f in views[n] for n in names) for f in range(n_frames)}
    frames = _select_frames({f: c for f, c in seen_by.items() if c > 0}, max_frames)
    for f in set(range(n_frames)) - set(frames):
        for n in names:
            if f in views[n]:
                dropped[n].append(DroppedView(f, views[n][f].source,
                                              "not selected (max_frames reached)"))
    say(f"starting the rig solve from {len(frames)} frames")
    ext0 = initial_extrinsics(names, tree, poses)
    pose0 = initial_board_poses(names, frames, ext0, poses,
                                {n: {f: len(v) for f, v in views[n].items()} for n in names})
    obs = [RigObservation(k, i, views[n][f]) for i, f in enumerate(frames)
           for k, n in enumerate(names) if f in views[n]]
    rig_cams = [RigCamera(cams[n].model, cams[n].K, cams[n].dist,
                          () if n in fixed else free_parameters(cams[n].model, options=options))
                for n in names]
    weighted = weighted and any(o.view.sigma_px is not None
                                and np.isfinite(o.view.sigma_px).any() for o in obs)
    apart = _not_simultaneous(names, rig_cams, ext0, pose0, obs, frames, cams, poses)
    if apart:  # left out, and the start made again without them
        for k, f, why in apart:
            dropped[names[k]].append(DroppedView(f, views[names[k]][f].source, why))
            del views[names[k]][f], poses[names[k]][f]
        tree = spanning_tree(names, _check_connected(names, views))
        ext0 = initial_extrinsics(names, tree, poses)
        pose0 = initial_board_poses(names, frames, ext0, poses,
                                    {n: {f: len(v) for f, v in views[n].items()}
                                     for n in names})
        obs = [RigObservation(k, i, views[n][f]) for i, f in enumerate(frames)
               for k, n in enumerate(names) if f in views[n]]

    # Step 4. Joint bundle adjustment, outliers out, weights re-scaled.
    say(f"joint bundle adjustment of {len(names)} cameras over {len(frames)} frames")
    sol = rig_bundle_adjust(obs, rig_cams, ext0, pose0, weighted=weighted)
    if points == "centers":
        obs = [RigObservation(o.camera, o.frame, lens_corrected_centers(
            o.view, _camera_of(sol, o.camera, sizes[names[o.camera]]))) for o in obs]
        sol = _again(obs, sol, weighted)
    _refuse_hopeless(names, tree, sol, obs, frames, cams, poses)
    outliers: dict[str, list[np.ndarray]] = {n: [] for n in names}
    points_dropped = 0
    for _round in range(8):
        kept, removed = _reject(obs, sol.residuals, board, names, dropped, outliers)
        if len(kept) == len(obs) and removed == 0:
            break
        points_dropped += removed
        obs, poses_kept, frames = _renumber(kept, sol.poses, frames)
        problem = connectivity_problem(names, shared_frame_counts(
            names, {n: {frames[o.frame] for o in obs if o.camera == k}
                    for k, n in enumerate(names)}))
        if problem is not None:
            raise CalibrationError(f"after dropping outliers: {problem}")
        sol = rig_bundle_adjust(obs, list(sol.cameras), sol.extrinsics, poses_kept,
                                weighted=weighted)
    if weighted:
        measured = obs
        for _round in range(REWEIGHT_ROUNDS):
            re = reweighted([o.view for o in measured], list(sol.residuals))
            obs = [RigObservation(o.camera, o.frame, v) for o, v in zip(measured, re,
                                                                       strict=True)]
            sol = _again(obs, sol, True)

    # Step 5. Results: cameras, pairs with their uncertainty, rectification.
    say("extrinsics' uncertainty and rectification")
    rig = rig_result(names, sizes, points, board, fixed, single, sol, obs, frames, dropped,
                     outliers, points_dropped, tree, time.monotonic() - start)

    # Step 6. The verdict: does one board pose per frame fit the cameras as well as their own?
    checks = check_pairs(
        names, tree, sol.residuals, obs, frames, cams, poses,
        {p: rig.pairs[p].baseline_m for p in tree},
        {n: int(sum(len(x) for x in outliers[n])) for n in names},
        {n: _own_dropped_share(single[n]) for n in names})
    reason = refusal(checks)
    if reason is not None:
        raise CalibrationError(reason)
    extra = warnings_of(checks)
    return replace(rig, warnings=(*rig.warnings, *extra)) if extra else rig


def _not_simultaneous(names: tuple[str, ...], rig_cams: list[RigCamera], ext0: np.ndarray,
                      pose0: np.ndarray, obs: list[RigObservation], frames: list[int],
                      cams: dict[str, CameraModel],
                      poses: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]]
                      ) -> list[tuple[int, int, str]]:
    """The observations to leave out as not simultaneous with the rest of their frame:
    (camera position, rig frame index, why). At the start (extrinsics the median over the
    frames, each frame's pose from the camera with the most points) a camera whose image
    shows the board elsewhere stands out; fitted in, it would pull the whole solve. A view
    its own camera does not fit either is left to the outlier rejection."""
    res = rig_residuals(obs, tuple(rig_cams), ext0, pose0)
    excess = observation_excess(res, obs, frames, [cams[n] for n in names],
                                [poses[n] for n in names])
    out = []
    for k in range(len(names)):
        mine = [(o, e, own) for o, (e, own) in zip(obs, excess, strict=True) if o.camera == k]
        if not mine:
            continue
        own_rms = float(np.median([own for _, _, own in mine]))
        limit = max(EXCESS_REFUSE_FACTOR * own_rms, EXCESS_REFUSE_PX,
                    APART_FACTOR * float(np.median([e for _, e, _ in mine])))
        out += [(k, frames[o.frame], f"not simultaneous with the rest of the frame: its own "
                 f"board pose is {e:.2f} px from the rig's")
                for o, e, own in mine if e > limit and own <= limit]
    return out


def _refuse_hopeless(names: tuple[str, ...], tree: list[tuple[str, str]], sol: RigSolution,
                     obs: list[RigObservation], frames: list[int],
                     cams: dict[str, CameraModel],
                     poses: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]]) -> None:
    """Refuse at once when most frames of a connecting pair disagree (images of different
    instants): dropping outliers cannot mend that, and would take long on such residuals."""
    baselines = {(a, b): float(np.linalg.norm(pair_transform(
        sol.extrinsics, names.index(a), names.index(b))[1])) for a, b in tree}
    checks = check_pairs(names, tree, sol.residuals, obs, frames, cams, poses, baselines,
                         {}, {})
    reason = refusal([c for c in checks if c.hopeless()])
    if reason is not None:
        raise CalibrationError(reason)


def _own_dropped_share(res: CalibrationResult | None) -> float:
    """The share of its points a camera's own calibration dropped as outliers."""
    if res is None:
        return 0.0
    kept = len(res.residuals_px)
    return res.points_dropped / max(kept + res.points_dropped, 1)


def _camera_of(sol: RigSolution, k: int, size: tuple[int, int]) -> CameraModel:
    c = sol.cameras[k]
    return CameraModel(c.model, c.K, c.dist, size)


def _again(obs: list[RigObservation], sol: RigSolution, weighted: bool) -> RigSolution:
    return rig_bundle_adjust(obs, list(sol.cameras), sol.extrinsics, sol.poses,
                             weighted=weighted)

