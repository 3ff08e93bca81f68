"""Where to hold the board next: the holdable pose whose view would shrink the projection
uncertainty the most (the live tier's ``next pose``).

The current estimate's information about the free intrinsics (the Jacobian of every view,
poses eliminated by a Schur complement, as :func:`intrinsic_covariance` computes it) is
added, for each candidate pose, to the information that candidate's view would bring (its
own Jacobian by the intrinsics A and by its pose B: A^T A - A^T B (B^T B)^-1 B^T A over the
board points that fall inside the image), and the projection uncertainty RMS over the image
(as :func:`parameter_effect_px` defines it) after that view follows. The best
:data:`LOOKAHEAD_TOP` candidates by it are ranked by the lowest RMS each reaches together
with the best second candidate; the first of the best pair wins.

The candidates (:mod:`~artcal_ros.core.live.guidance_candidates`) are poses a person can
hold: the board facing the camera or tilted 20, 35 or 50 degrees towards one of eight
directions, over the image's centre, edges or corners, its visible part covering 15-85 % of
the image. Before the first solve :func:`~artcal_ros.core.live.guidance_start.first_pose`
ranks them with a provisional camera.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.model import free_columns, free_jacobian
from artcal_ros.core.calibrate.quality import image_grid, intrinsic_covariance, solution_camera
from artcal_ros.core.calibrate.solve import (
    Solution,
    ViewPoints,
    point_weights,
    project_jacobian,
    residuals,
)
from artcal_ros.core.camera import CameraModel
from artcal_ros.core.live.guidance_candidates import (
    REGIONS,
    TILT_DIRECTIONS,
    board_centre,
    board_points,
    candidates,
    place,
    tilt_rotation,
    views_information,
)

__all__ = ["MATCH_THRESHOLD", "REGIONS", "TILT_DIRECTIONS", "NextPose", "board_outline",
           "clip_polygon", "holdable_pose", "next_pose", "pose_match"]

# The live board matches the suggested pose at or above this outline overlap (IoU).
MATCH_THRESHOLD = 0.8
MIN_FILL, MAX_FILL = 0.15, 0.85  # visible share of the image a candidate may cover
CLOSER, FARTHER = 0.85, 1.18  # distance ratios to the typical view's named as a change
LOOKAHEAD_TOP = 40  # the best candidates by one view, ranked by the best pair they begin


@dataclass(frozen=True)
class NextPose:
    """A suggested board pose and what its view is expected to bring.

    Attributes:
        text: the pose in words, e.g. "bottom-left corner, closer, tilted left 45 deg".
        region: where in the image the board goes ("centre", "top edge", ...).
        distance: "closer", "farther" or "same distance" than the typical view so far.
        tilt_direction: "right", "up-left", ... ("" facing the camera).
        tilt_deg: angle between the board's normal and the optical axis, degrees.
        outline_px: (K, 2) float64 pixels, the board's outline where it should appear,
            clipped to the image.
        rvec, tvec: (3,) T_cam_board of the pose (Rodrigues, metres).
        uncertainty_rms_px: projection uncertainty RMS over the image expected after the view.
        current_uncertainty_rms_px: the same now.
    """

    text: str
    region: str
    distance: str
    tilt_direction: str
    tilt_deg: float
    outline_px: np.ndarray
    rvec: np.ndarray
    tvec: np.ndarray
    uncertainty_rms_px: float
    current_uncertainty_rms_px: float


def holdable_pose(camera_matrix: np.ndarray, board: Board, image_size: tuple[int, int], *,
                  anchor: tuple[float, float], fill: float, tilt_direction_deg: float,
                  tilt_deg: float, roll_deg: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """T_cam_board of the board held over a part of the image: (rvec (3,), tvec (3,)).

    The board's centre is at the distance where, facing the camera, it covers ``fill`` of
    the image area; it is tilted by ``tilt_deg`` so that its side in image direction
    ``tilt_direction_deg`` (0 right, 90 down) is farther away, rolled by ``roll_deg`` about
    its normal, and shifted so that its pinhole image touches the image border at
    ``anchor`` ((0, 0) top-left corner, (0.5, 0.5) centred, (1, 1) bottom-right corner;
    values between place it between).

    Args:
        camera_matrix: (3, 3) pixels (distortion is left out of the placement).
        image_size: (width, height), pixels.
    """
    R = tilt_rotation(tilt_direction_deg, tilt_deg, roll_deg)
    T = place(np.asarray(camera_matrix, dtype=np.float64), board, image_size,
               np.array([anchor], np.float64), np.array([fill], np.float64), R[None])[0]
    return cv2.Rodrigues(R)[0].ravel(), T - R @ board_centre(board)


def next_pose(views: Sequence[ViewPoints], sol: Solution, board: Board,
              image_size: tuple[int, int], *, weighted: bool = False,
              covariance: tuple[np.ndarray, float] | None = None) -> NextPose | None:
    """The holdable board pose whose view would lower the projection uncertainty the most.

    Args:
        views: the views of the current solve (their points tell the points mode: marker
            centres, marker corners or the board's points).
        sol: the current solve of ``views``.
        board: the board being shown.
        image_size: (width, height), pixels.
        weighted: the solve weighted points by :func:`point_weights` (a candidate's points
            then get the median weight of the current points).
        covariance: (covariance, residual sigma) of the free intrinsics as
            :func:`intrinsic_covariance` returns it for this solve, if already known.

    Returns:
        the suggestion, or None when the current estimate has no usable covariance or no
        candidate shows the board.
    """
    if len(views) == 0 or len(sol.free) == 0:
        return None
    if covariance is None:
        covariance = intrinsic_covariance(views, sol, residuals(list(views), sol),
                                          weighted=weighted)
    cov, sigma = covariance
    if not (np.all(np.isfinite(cov)) and math.isfinite(sigma) and sigma > 0):
        return None
    try:
        info = np.linalg.inv(cov) * sigma ** 2
    except np.linalg.LinAlgError:
        return None
    groups = free_columns(sol.model, sol.free)
    grid_M, n_grid = _grid_metric(sol, image_size, groups)
    if n_grid == 0:
        return None
    current = math.sqrt(max(float(np.trace(cov @ grid_M)) / n_grid, 0.0))
    points, weight = board_points(views, board)
    if weighted:
        weight *= float(np.median(np.concatenate([point_weights(v) for v in views])))
    cam = solution_camera(sol, image_size)
    r_max = _field_radius(cam)
    typical = _typical_depth(views, sol, board)
    cands = candidates(sol, board, image_size)
    fills = _visible_fills(board, cands.R, cands.T, cam, r_max)
    cands = cands.subset((fills >= MIN_FILL) & (fills <= MAX_FILL))
    infos, ok = views_information(points, board_centre(board), cands, sol, groups, image_size,
                                  r_max)
    cands = cands.subset(ok)
    if len(cands.T) == 0:
        return None
    infos = infos[ok] * weight
    try:
        rms = _rms_after(info, infos, sigma, grid_M, n_grid)
        # Greedy one view at a time can pick a view that leaves no good partner: the best
        # few by one view are ranked by the best pair of views they begin.
        top = np.argsort(rms)[:LOOKAHEAD_TOP]
        k = int(top[int(np.argmin(_best_two(info, infos[top], infos, sigma, grid_M,
                                             n_grid)))])
    except np.linalg.LinAlgError:
        return None
    anchor = (float(cands.anchors[k, 0]), float(cands.anchors[k, 1]))
    direction, tilt = int(cands.direction[k]), float(cands.tilt_deg[k])
    rvec, tvec = cands.rvecs[k].copy(), cands.T[k] - cands.R[k] @ board_centre(board)
    after = float(rms[k])
    depth = float(cands.T[k, 2])  # of the board's centre
    distance = ("same distance" if not math.isfinite(typical)
                else "closer" if depth < CLOSER * typical
                else "farther" if depth > FARTHER * typical else "same distance")
    region = REGIONS[anchor]
    tilt_word = TILT_DIRECTIONS[direction] if tilt > 0 else ""
    tilt_text = f"tilted {tilt_word} {tilt:.0f} deg" if tilt > 0 else "facing the camera"
    return NextPose(f"{region}, {distance}, {tilt_text}", region, distance, tilt_word,
                    float(tilt), board_outline(board, rvec, tvec, sol, image_size),
                    rvec, tvec, after, current)


def _rms_after(info: np.ndarray, added: np.ndarray, sigma: float, grid_M: np.ndarray,
               n_grid: int) -> np.ndarray:
    """(N,) projection uncertainty RMS over the image after adding each of N views'
    information (N, p, p) to ``info`` (p, p)."""
    covs = np.linalg.inv(info[None] + added) * sigma ** 2
    return np.sqrt(np.maximum(np.einsum("cij,ji->c", covs, grid_M) / n_grid, 0.0))


def _best_two(info: np.ndarray, first: np.ndarray, then: np.ndarray, sigma: float,
              grid_M: np.ndarray, n_grid: int) -> np.ndarray:
    """(N,) the lowest projection uncertainty RMS after each of N views (``first``
    (N, p, p)) and the best of ``then`` (C, p, p) after it."""
    out = np.empty(len(first))
    for k in range(len(first)):
        out[k] = float(_rms_after(info + first[k], then, sigma, grid_M, n_grid).min())
    return out


def _grid_metric(sol: Solution, image_size: tuple[int, int],
                 groups: list[tuple[int, ...]]) -> tuple[np.ndarray, int]:
    """(G^T G (p, p), N): G the projection's derivatives by the free intrinsics at the N
    grid pixels :func:`parameter_effect_px` uses, so RMS^2 = trace(cov G^T G) / N."""
    cam = solution_camera(sol, image_size)
    pix = image_grid(image_size, max(image_size) / 24.0)
    rays, ok = cam.unproject(pix)
    if not np.any(ok):
        return np.zeros((len(groups), len(groups))), 0
    A, _ = project_jacobian(rays[ok], np.zeros(3), np.zeros(3), sol.camera_matrix,
                            sol.dist_coeffs, sol.model)
    G = free_jacobian(A, groups)
    return G.T @ G, int(np.count_nonzero(ok))


def _field_radius(cam: CameraModel) -> float:
    """Largest tan(angle from the optical axis) of a ray the image shows (a little beyond
    the image border's rays): points farther out fold back under a distortion model."""
    w, h = cam.size
    t = np.linspace(0.0, 1.0, 9)
    border = np.concatenate([np.stack([t * (w - 1), np.zeros_like(t)], 1),
                             np.stack([t * (w - 1), np.full_like(t, h - 1)], 1),
                             np.stack([np.zeros_like(t), t * (h - 1)], 1),
                             np.stack([np.full_like(t, w - 1), t * (h - 1)], 1)])
    rays, ok = cam.unproject(border)
    if not np.any(ok):
        return 1.0
    r = np.hypot(rays[ok, 0], rays[ok, 1]) / rays[ok, 2]
    return float(r.max()) * 1.05


def _typical_depth(views: Sequence[ViewPoints], sol: Solution, board: Board) -> float:
    """Median distance along the optical axis of the board's centre over the views, m."""
    c = board_centre(board)
    z = [float((cv2.Rodrigues(r)[0] @ c + t)[2]) for r, t in zip(sol.rvecs, sol.tvecs,
                                                                   strict=True)]
    return float(np.median(z)) if z else float("nan")


def board_outline(board: Board, rvec: np.ndarray, tvec: np.ndarray, sol: Solution,
                  image_size: tuple[int, int], *, per_side: int = 12) -> np.ndarray:
    """(K, 2) float64 pixels: the board's outer edge for pose T_cam_board, clipped to the
    image (empty when none of it is in view).

    Points beyond the lens's field are pulled back to its edge before projection, so a
    distortion model's fold does not bring them back into the image.

    Args:
        per_side: points along each of the four sides.
    """
    cam = solution_camera(sol, image_size)
    outline = _project_outline(board, rvec, tvec, cam, per_side, _field_radius(cam))
    return clip_polygon(outline, image_size) if len(outline) >= 3 else outline


def _project_outline(board: Board, rvec: np.ndarray, tvec: np.ndarray, cam: CameraModel,
                     per_side: int, r_max: float) -> np.ndarray:
    """(K, 2) pixels, the board's outer edge through the lens (not clipped; points behind
    the camera left out, points beyond the field ``r_max`` pulled back to it)."""
    R = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
    cam_pts = _outline_points(board, per_side) @ R[:, :2].T + np.asarray(tvec, np.float64)
    cam_pts = cam_pts[cam_pts[:, 2] > 1e-6]
    if len(cam_pts) < 3:
        return np.zeros((0, 2))
    return _through_lens(cam_pts, cam, r_max)


def _outline_points(board: Board, per_side: int) -> np.ndarray:
    """(4 per_side, 2) board-frame x, y along the board's outer edge, metres."""
    x0, y0, x1, y1 = board.extent_m
    s = np.linspace(0.0, 1.0, per_side, endpoint=False)
    return np.concatenate([
        np.stack([x0 + s * (x1 - x0), np.full_like(s, y0)], 1),
        np.stack([np.full_like(s, x1), y0 + s * (y1 - y0)], 1),
        np.stack([x1 - s * (x1 - x0), np.full_like(s, y1)], 1),
        np.stack([np.full_like(s, x0), y1 - s * (y1 - y0)], 1)])


def _through_lens(cam_pts: np.ndarray, cam: CameraModel, r_max: float) -> np.ndarray:
    """(N, 2) pixels of camera-frame points (N, 3), those beyond the field ``r_max`` pulled
    back to it first (a distortion model's fold would bring them back into the image)."""
    z = np.where(cam_pts[:, 2] > 1e-6, cam_pts[:, 2], 1e-6)
    xy = cam_pts[:, :2] / z[:, None]
    r = np.hypot(xy[:, 0], xy[:, 1])
    xy = xy * np.minimum(1.0, r_max / np.maximum(r, 1e-12))[:, None]
    return np.asarray(cam.project_cv(np.hstack([xy, np.ones((len(xy), 1))])), np.float64)


def clip_polygon(poly: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """(K, 2) the polygon (N, 2) pixels cut to the image [0, W-1] x [0, H-1]
    (Sutherland-Hodgman)."""
    w, h = image_size
    out = [np.asarray(p, np.float64) for p in poly]
    # each edge of the image as (axis, limit, keep when coordinate >= limit)
    for axis, limit, above in ((0, 0.0, True), (0, w - 1.0, False), (1, 0.0, True),
                               (1, h - 1.0, False)):
        if not out:
            break
        pts, out = out, []
        for i, cur in enumerate(pts):
            prev = pts[i - 1]
            cin = cur[axis] >= limit if above else cur[axis] <= limit
            pin = prev[axis] >= limit if above else prev[axis] <= limit
            if cin != pin:
                f = (limit - prev[axis]) / (cur[axis] - prev[axis])
                out.append(prev + f * (cur - prev))
            if cin:
                out.append(cur)
    return np.array(out, np.float64).reshape(-1, 2)


def _visible_fills(board: Board, R: np.ndarray, T: np.ndarray, cam: CameraModel,
                   r_max: float) -> np.ndarray:
    """(C,) share of the image area the board covers for each pose (R_cam_board (C, 3, 3),
    the board centre's camera-frame position T (C, 3)): its outline through the lens,
    eight points, cut to the image."""
    if len(T) == 0:
        return np.zeros(0)
    edge = np.hstack([_outline_points(board, 2), np.zeros((8, 1))]) - board_centre(board)
    cam_pts = np.einsum("cij,kj->cki", R, edge) + T[:, None, :]
    front = np.all(cam_pts[..., 2] > 1e-6, axis=1)
    px = _through_lens(cam_pts.reshape(-1, 3), cam, r_max).reshape(len(T), -1, 2)
    w, h = cam.size
    image = np.array([[0, 0], [w - 1, 0], [w - 1, h - 1], [0, h - 1]], np.float32)
    out = np.zeros(len(T))
    for k in np.flatnonzero(front):
        inter, _ = cv2.intersectConvexConvex(cv2.convexHull(px[k].astype(np.float32)), image)
        out[k] = float(inter) / float((w - 1) * (h - 1))
    return out


def pose_match(suggestion: NextPose, live_points_px: np.ndarray) -> float:
    """How well the live board matches the suggested pose, in [0, 1].

    The overlap (intersection over union) of the convex hull of the live board's image
    points and that of the suggested outline: 1 when they cover the same part of the
    image, 0 when they do not touch.

    Args:
        suggestion: from :func:`next_pose`.
        live_points_px: the live board's image points, pixels: marker corners (N, 4, 2),
            points (N, 2) or its outline (K, 2).
    """
    flat = np.asarray(live_points_px, dtype=np.float64).reshape(-1, 2)
    pts = flat[np.all(np.isfinite(flat), axis=1)]
    if len(pts) < 3 or len(suggestion.outline_px) < 3:
        return 0.0
    live = cv2.convexHull(pts.astype(np.float32))
    want = cv2.convexHull(suggestion.outline_px.astype(np.float32))
    a_live = float(cv2.contourArea(live))
    a_want = float(cv2.contourArea(want))
    if a_live <= 0 or a_want <= 0:
        return 0.0
    inter, _ = cv2.intersectConvexConvex(live, want)
    union = a_live + a_want - float(inter)
    return float(min(max(inter / union, 0.0), 1.0)) if union > 0 else 0.0
