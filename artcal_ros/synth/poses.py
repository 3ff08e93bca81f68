"""Realistic board poses for the renderer: whole-board views, close partial views, smooth motion.

A pose is T_cam_board as (rvec (3,), tvec (3,) metres): ``p_cam = R(rvec) p_board + tvec``.
Views are built the way a person holds a camera in front of a board: the optical
axis aims at a point on the board, tilted up to ``max_tilt_deg`` away from the
board's normal in a random direction, rolled a little, at a distance where the
whole board fits in the image (full views) or much closer so the board overfills
it (partial views). Every view is checked with the exact projection: enough
markers fully inside the image, markers not too small.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.errors import ParameterError
from artcal_ros.synth.camera import Camera, field_radius, project_points

Pose = tuple[np.ndarray, np.ndarray]


def marker_truth(board: Board, cam: Camera, rvec: np.ndarray,
                 tvec: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """True image of every marker of the board for the pose T_cam_board.

    Returns:
        corners_px: (N, 4, 2) float64 pixels, TL TR BR BL (NaN for points behind the camera);
        centers_px: (N, 2) float64 pixels, image of each square's centre;
        inside: (N,) bool, all 4 corners in front of the camera, within the image
            ([0, W-1] x [0, H-1]) and within the field the lens maps onto the image;
        side_px: (N,) float64, the shortest side of each marker's image quad, pixels.
    """
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    t = np.asarray(tvec, dtype=np.float64).reshape(3)
    obj = board.object_corners()
    n = obj.shape[0]
    pts = np.concatenate([obj.reshape(-1, 3), board.object_centers()])
    cam_pts = pts @ R.T + t
    px = project_points(cam, cam_pts)
    corners = px[:4 * n].reshape(n, 4, 2)
    centers = px[4 * n:]
    w, h = cam.size
    with np.errstate(invalid="ignore"):
        in_img = ((corners[..., 0] >= 0) & (corners[..., 0] <= w - 1)
                  & (corners[..., 1] >= 0) & (corners[..., 1] <= h - 1))
        in_field = field_radius(cam, cam_pts[:4 * n]) <= cam.max_field_radius()
    inside = np.asarray((in_img & in_field.reshape(n, 4)).all(axis=1))
    sides = np.linalg.norm(corners - np.roll(corners, -1, axis=1), axis=2)
    return np.asarray(corners), np.asarray(centers), inside, np.asarray(sides.min(axis=1))


def point_truth(board: Board, cam: Camera, rvec: np.ndarray,
                tvec: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """True image of every point of the board (saddle points) for the pose T_cam_board.

    Returns:
        points_px: (M, 2) float64 pixels, in ``board.point_ids`` order (NaN behind the camera);
        inside: (M,) bool, in front of the camera, within the image and the lens's field;
        spacing_px: (M,) float64, distance to the nearest grid neighbour's image, pixels.
    """
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    t = np.asarray(tvec, dtype=np.float64).reshape(3)
    cam_pts = board.object_points() @ R.T + t
    px = np.asarray(project_points(cam, cam_pts))
    w, h = cam.size
    with np.errstate(invalid="ignore"):
        inside = ((px[:, 0] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)
                  & (field_radius(cam, cam_pts) <= cam.max_field_radius()))
    rc = board.point_cells(board.point_ids)
    grid = np.full((rc[:, 0].max() + 3, rc[:, 1].max() + 3, 2), np.nan)
    grid[rc[:, 0] + 1, rc[:, 1] + 1] = px
    # grid neighbours: along rows and columns (an asymmetric circle grid's cells are a
    # chequer: its neighbours are diagonal)
    steps = ((1, 1), (1, -1)) if board.board_type == "acircles" else ((0, 1), (1, 0))
    r, c = rc[:, 0] + 1, rc[:, 1] + 1
    gaps = [np.linalg.norm(grid[r + sr * dr, c + sr * dc] - px, axis=1)
            for dr, dc in steps for sr in (-1, 1)]
    spacing = np.nanmin(np.stack(gaps), axis=0)
    return px, np.asarray(inside), np.asarray(spacing)


def feature_visibility(board: Board, cam: Camera, rvec: np.ndarray,
                       tvec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(inside (K,) bool, size_px (K,)) of the board's correspondences for a pose: its markers
    (shortest side), or its points (grid spacing) plus the pattern's four outer corners (so
    that every entry inside means the whole board is in view)."""
    if not board.has_points:
        _, _, inside, side = marker_truth(board, cam, rvec, tvec)
        return inside, side
    _, inside, spacing = point_truth(board, cam, rvec, tvec)
    x0, y0, x1, y1 = board.extent_m
    outer = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    cam_pts = outer @ R.T + np.asarray(tvec, dtype=np.float64).reshape(3)
    px = np.asarray(project_points(cam, cam_pts))
    w, h = cam.size
    with np.errstate(invalid="ignore"):
        out_in = ((px[:, 0] >= 0) & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1)
                  & (field_radius(cam, cam_pts) <= cam.max_field_radius()))
    return (np.concatenate([inside, out_in]),
            np.concatenate([spacing, np.full(4, np.nanmedian(spacing))]))


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    return np.asarray(cv2.Rodrigues((np.asarray(axis, dtype=np.float64) * angle).reshape(3, 1))[0])


def _pose_from(C: np.ndarray, R_board_cam: np.ndarray) -> Pose:
    R = R_board_cam.T
    rvec = cv2.Rodrigues(R)[0].ravel()
    return rvec, -R @ C


def _aim(board: Board, target: np.ndarray, R_board_cam: np.ndarray, dist: float) -> Pose:
    return _pose_from(target - dist * R_board_cam[:, 2], R_board_cam)


def _fit_distance(board: Board, cam: Camera, target: np.ndarray, R_bc: np.ndarray,
                  lo: float, hi: float) -> float | None:
    """Smallest distance (within [lo, hi]) at which every marker is inside the image."""
    def all_in(d: float) -> bool:
        return bool(feature_visibility(board, cam, *_aim(board, target, R_bc, d))[0].all())
    if not all_in(hi):
        return None
    for _ in range(24):
        mid = math.sqrt(lo * hi)
        if all_in(mid):
            hi = mid
        else:
            lo = mid
    return hi


def random_poses(board: Board, cam: Camera, n: int, rng: np.random.Generator, *,
                 partial_fraction: float = 0.3, min_inside: int = 8,
                 min_distance: float = 0.3, max_distance: float = 2.5,
                 max_tilt_deg: float = 55.0, max_roll_deg: float = 35.0,
                 roll_centre_deg: float = 0.0) -> list[Pose]:
    """``n`` random, realistic, calibration-worthy views T_cam_board.

    Args:
        partial_fraction: share of views so close that the board overfills the image.
        min_inside: markers that must be fully inside the image in every view.
        min_distance, max_distance: camera-to-aim-point distance range, metres (partial
            views of a board small enough to fit the image from closer than
            ``min_distance / 0.6`` come from 0.4 - 0.85 times that fitting distance).
        max_tilt_deg: largest angle between the optical axis and the board normal.
        max_roll_deg: largest roll about the optical axis, either side of ``roll_centre_deg``.
        roll_centre_deg: the board's usual roll: 90 holds a board whose long side is its y
            axis (OpenCV's 4 x 11 asymmetric circle grid) across a landscape image, as one
            holds it to reach the image's sides.

    Returns:
        list of (rvec (3,), tvec (3,) metres).
    """
    if n < 0 or not 0 <= partial_fraction <= 1:
        raise ParameterError(f"random_poses: need n >= 0 and 0 <= partial_fraction <= 1 "
                             f"(got n={n}, partial_fraction={partial_fraction})")
    n_partial = round(n * partial_fraction)
    kinds = np.array([True] * n_partial + [False] * (n - n_partial))
    rng.shuffle(kinds)
    w_m, h_m = board.size_m
    x0, y0 = board.extent_m[:2]
    center = np.array([x0 + w_m / 2, y0 + h_m / 2, 0.0])
    poses: list[Pose] = []
    for partial in kinds:
        for _attempt in range(300):
            phi = rng.uniform(0, 2 * math.pi)
            tilt = math.radians(rng.uniform(5.0, max_tilt_deg))
            roll = math.radians(roll_centre_deg + rng.uniform(-max_roll_deg, max_roll_deg))
            R_bc = _rot(np.array([math.cos(phi), math.sin(phi), 0.0]), tilt) @ _rot(
                np.array([0.0, 0.0, 1.0]), roll)
            if partial:
                target = np.array([x0 + rng.uniform(0.1, 0.9) * w_m,
                                   y0 + rng.uniform(0.1, 0.9) * h_m, 0])
                fit = _fit_distance(board, cam, center, R_bc, min_distance, 4 * max_distance)
                fit = fit if fit is not None else max_distance
                lo, top = min_distance, min(max_distance, 0.6 * fit)
                if top <= lo:
                    # a small board, whole in view from closer than min_distance: go nearer
                    lo, top = 0.4 * fit, 0.85 * fit
                dist = math.exp(rng.uniform(math.log(lo), math.log(top)))
            else:
                target = center + np.array([rng.uniform(-0.08, 0.08) * w_m,
                                            rng.uniform(-0.08, 0.08) * h_m, 0.0])
                fit = _fit_distance(board, cam, target, R_bc, min_distance, max_distance)
                if fit is None:
                    continue
                dist = min(fit * rng.uniform(1.02, 1.3), max_distance)
            rvec, tvec = _aim(board, target, R_bc, dist)
            inside, side = feature_visibility(board, cam, rvec, tvec)
            if inside.sum() < min_inside or np.median(side[inside]) < 8.0:
                continue
            if partial and inside.all():
                continue
            if not partial and not inside.all():
                continue
            poses.append((rvec, tvec))
            break
        else:
            raise ParameterError(
                f"random_poses: could not place a {'partial' if partial else 'full'} view with "
                f"{min_inside} markers inside a {cam.width}x{cam.height} image; the board may "
                "be too small or too large for this camera, or the distance range too narrow")
    return poses


def _slerp(Ra: np.ndarray, Rb: np.ndarray, s: float) -> np.ndarray:
    """Rotation a fraction ``s`` of the way from Ra to Rb (shortest arc)."""
    d = cv2.Rodrigues(Ra.T @ Rb)[0].ravel()
    return np.asarray(Ra @ cv2.Rodrigues(d * s)[0])


def smooth_poses(board: Board, cam: Camera, n: int, rng: np.random.Generator, *,
                 frames_per_key: int = 10, **kwargs: float) -> list[Pose]:
    """``n`` views of a camera moved smoothly between random key views (a hand-held sweep).

    Key views come from :func:`random_poses` (``kwargs`` are passed on); between them the
    camera centre and orientation are eased (smoothstep) so motion starts and stops gently.
    Views between key views are not checked: a few may show fewer markers.
    """
    if n <= 0:
        return []
    n_keys = max(2, math.ceil((n - 1) / frames_per_key) + 1)
    keys = random_poses(board, cam, n_keys, rng, **kwargs)  # type: ignore[arg-type]
    return ease_between(keys, n, frames_per_key=frames_per_key)


def ease_between(keys: list[Pose], n: int, *, frames_per_key: int = 10) -> list[Pose]:
    """``n`` poses T_x_board moved smoothly through the key poses, ``frames_per_key`` apart.

    The origin of frame x (a camera, or a rig's reference) and its orientation are eased
    (smoothstep) between consecutive keys, so motion starts and stops gently; at least two
    keys are needed, and keys beyond the ``n`` frames are unused.
    """
    if n <= 0:
        return []
    if len(keys) < 2:
        raise ParameterError(f"ease_between: need at least 2 key poses, got {len(keys)}")
    n_keys = len(keys)
    centers, rots = [], []
    for rvec, tvec in keys:
        R = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
        rots.append(R.T)              # R_board_x
        centers.append(-R.T @ np.asarray(tvec, np.float64).reshape(3))  # x's origin, board frame
    poses: list[Pose] = []
    for i in range(n):
        k, frac = divmod(i / frames_per_key, 1.0)
        k = int(min(k, n_keys - 2))
        if i / frames_per_key >= n_keys - 1:
            frac = 1.0
        s = frac * frac * (3.0 - 2.0 * frac)
        C = (1 - s) * centers[k] + s * centers[k + 1]
        poses.append(_pose_from(C, _slerp(rots[k], rots[k + 1], s)))
    return poses
