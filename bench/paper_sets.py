"""The paper's Figure 5: how many images a calibration needs, evaluated its way and against truth.

Run by :mod:`bench.paper`. Per camera, a pool of random views of the default 19 x 9 board
(30 % of them so close that the board overfills the image) is rendered under the renderer's
clean light and detected once. For each set size, ten random subsets of the pool are
calibrated (``artcal_ros.calibrate``, centres and corners, no cross-validation), and each
calibration is evaluated:

- the paper's way: its intrinsics held fixed, every pose of the whole pool re-estimated
  from the pool's detected points (the same points mode; those the whole pool's own
  calibration accepts, within 1 px of it), then the residuals' standard deviation (per
  coordinate) and largest length; mean over the subsets;
- against the truth: projection difference from the true camera (RMS over the image),
  mean over the subsets.

"Enough" is the smallest set size from which every larger size's mean is within 10 % of
the largest size's.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

import numpy as np

from artcal_ros import Board, calibrate, detect
from artcal_ros.core.calibrate.model import ViewPoints, estimate_pose, refine_pose
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.calibrate.views import view_points
from artcal_ros.core.errors import ArtcalError
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
from bench.paper_table2 import MODELS

POINTS = ("centers", "corners")
OUTLIER_PX = 1.0
METRICS = ("std", "max", "proj RMS")


def _pool(cam: Camera, board: Board, n: int, seed: int) -> list[Any]:
    rng = np.random.default_rng(seed)
    return [detect(render_view(board, cam, r, t, photometry=Photometry.clean(), rng=rng).image,
                   board) for r, t in random_poses(board, cam, n, rng)]


def _errors(est: Any, views: list[ViewPoints], start: list[Any]) -> tuple[float, float]:
    """(std, max) px of the pool's residuals with ``est``'s intrinsics, each pose refined
    from ``start`` (the poses under the whole pool's own calibration)."""
    res = []
    for view, pose in zip(views, start, strict=True):
        if pose is None:
            continue
        rvec, tvec, _ = refine_pose(view, est.K, est.dist, est.model, *pose)
        res.append(view.image_points - est.project(view.object_points, rvec, tvec))
    r = np.concatenate(res)
    r = r[np.all(np.isfinite(r), axis=1)]
    return float(np.sqrt(np.mean(np.var(r, axis=0)))), float(np.linalg.norm(r, axis=1).max())


def _accepted(views: list[ViewPoints], ref: Any) -> tuple[list[ViewPoints], list[Any]]:
    """The pool's points the whole pool's calibration ``ref`` accepts (residual <= 1 px, as
    its solve drops outliers) and each view's pose under it (None: fewer than 4 points)."""
    kept, poses = [], []
    for v in views:
        pose = None
        if len(v.image_points) >= 4:
            try:
                pose = estimate_pose(v, ref.K, ref.dist, ref.model)
            except ArtcalError:
                pose = None
        if pose is not None:
            e = np.linalg.norm(v.image_points - ref.project(v.object_points, *pose), axis=1)
            ok = e <= OUTLIER_PX
            v = replace(v, object_points=v.object_points[ok], image_points=v.image_points[ok],
                        marker_ids=v.marker_ids[ok], marker_corners_px=None, sigma_px=None)
            pose = pose if ok.sum() >= 4 else None
        kept.append(v)
        poses.append(pose)
    return kept, poses


def set_sizes_camera(camera: str, sizes: tuple[int, ...], subsets: int, pool: int,
                     seed: int) -> dict[str, Any]:
    """{"camera", "sizes", "<points> <metric>": (S,) mean per size, "failed": solves that
    failed per points mode} for one camera."""
    cam = Camera.preset(camera)
    model, k_coeffs = MODELS[camera]
    board = Board()
    dets = _pool(cam, board, pool, seed)
    rng = np.random.default_rng(seed + 1)
    out: dict[str, Any] = {"camera": camera, "sizes": list(sizes)}
    for points in POINTS:
        views = [view_points(d, board, points, k) for k, d in enumerate(dets)]
        ref = calibrate(dets, board, image_size=cam.size, model=model, points=points,
                        k_coefficients=k_coeffs, cross_validation_folds=0).camera
        views, start = _accepted(views, ref)
        means = {m: [] for m in METRICS}
        failed = 0
        for n in sizes:
            got: dict[str, list[float]] = {m: [] for m in METRICS}
            for _ in range(subsets):
                pick = sorted(rng.choice(len(dets), size=n, replace=False))
                try:
                    est = calibrate([dets[k] for k in pick], board, image_size=cam.size,
                                    model=model, points=points, k_coefficients=k_coeffs,
                                    cross_validation_folds=0, accept_weak=True).camera
                except ArtcalError:
                    failed += 1
                    continue
                std, worst = _errors(est, views, start)
                got["std"].append(std)
                got["max"].append(worst)
                got["proj RMS"].append(projection_difference(cam, est)[0])
            for m in METRICS:
                means[m].append(float(np.mean(got[m])) if got[m] else math.nan)
        for m in METRICS:
            out[f"{points} {m}"] = means[m]
        out[f"{points} failed"] = failed
    return out


def enough(sizes: list[int], means: list[float], within: float = 0.10) -> int | None:
    """Smallest size from which every larger size's mean is within ``within`` of the
    largest size's (None when the largest size's is not finite)."""
    last = means[-1]
    if not math.isfinite(last):
        return None
    best = sizes[-1]
    for n, v in zip(reversed(sizes), reversed(means), strict=True):
        if not (math.isfinite(v) and abs(v - last) <= within * last):
            break
        best = n
    return best
