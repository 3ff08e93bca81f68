"""Where to hold the board next: the holdable pose whose view would shrink the projection
uncertainty the most (the live tier's ``next pose``).

The current estimate's information about the free intrinsics (the Jacobian of every view,
poses eliminated by a Schur complement, as :func:`intrinsic_covariance` computes it) is
added, for each candidate pose, to the information that candidate's view would bring (its
own Jacobian by the intrinsics A and by its pose B: A^T A - A^T B (B^T B)^-1 B^T A over the
board points that fall inside the image). The candidate whose sum gives the lowest
projection uncertainty RMS over the image (as :func:`parameter_effect_px` defines it) wins.

Candidates are poses a person can hold: the board filling 20-80 % of the image, facing the
camera or tilted 25 or 45 degrees towards one of eight directions, placed over the image's
centre, its four edges or its four corners. "Tilted left" means the board's face turned
towards the image's left: its left edge farther from the camera than its right.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.model import free_columns, free_jacobian, project_with_jacobian
from artcal_ros.core.calibrate.quality import image_grid, intrinsic_covariance, solution_camera
from artcal_ros.core.calibrate.solve import (
    Solution,
    ViewPoints,
    point_weights,
    project_jacobian,
    residuals,
)
from artcal_ros.core.camera import CameraModel

# The live board matches the suggested pose at or above this outline overlap (IoU).
MATCH_THRESHOLD = 0.8
FILLS = (0.25, 0.45, 0.7)       # share of the image area the board covers, facing the camera
TILTS_DEG = (25.0, 45.0)
TILT_DIRECTIONS = ("right", "down-right", "down", "down-left", "left", "up-left", "up",
                   "up-right")  # every 45 degrees, image x right, y down
# (anchor x, anchor y) as fractions of the image -> the region's name
REGIONS = {(0.0, 0.0): "top-left corner", (0.5, 0.0): "top edge", (1.0, 0.0): "top-right corner",
           (0.0, 0.5): "left edge", (0.5, 0.5): "centre", (1.0, 0.5): "right edge",
           (0.0, 1.0): "bottom-left corner", (0.5, 1.0): "bottom edge",
           (1.0, 1.0): "bottom-right corner"}
MIN_FILL, MAX_FILL = 0.15, 0.85  # visible share of the image a candidate may cover
MAX_POINTS = 160  # board points a candidate's information is computed from (scaled to all)
MARGIN = 0.02     # of the image size, between a placed board and the image border
CLOSER, FARTHER = 0.85, 1.18  # distance ratios to the typical view's named as a change


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
    R = _tilt_rotation(tilt_direction_deg, tilt_deg, roll_deg)
    T = _place(np.asarray(camera_matrix, dtype=np.float64), board, image_size,
               np.array([anchor], np.float64), np.array([fill], np.float64), R[None])[0]
    return cv2.Rodrigues(R)[0].ravel(), T - R @ _centre(board)


def _tilt_rotation(direction_deg: float, tilt_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """(3, 3) R_cam_board of a board rolled by ``roll_deg`` about its normal, then turned
    by ``tilt_deg`` so that its side towards image direction ``direction_deg`` recedes."""
    phi, tilt = math.radians(direction_deg), math.radians(tilt_deg)
    # The axis in the image plane about which the side towards phi turns away (+z).
    axis = np.array([math.sin(phi), -math.cos(phi), 0.0])
    return np.asarray(cv2.Rodrigues((axis * tilt).reshape(3, 1))[0]
                      @ cv2.Rodrigues(np.array([0.0, 0.0, math.radians(roll_deg)]))[0])


def _place(K: np.ndarray, board: Board, image_size: tuple[int, int], anchors: np.ndarray,
           fills: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(C, 3) camera-frame position of the board's centre for C placements (anchors (C, 2),
    fills (C,), orientations R_cam_board (C, 3, 3)), as :func:`holdable_pose` places it."""
    w, h = image_size
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    bw, bh = board.size_m
    x0, y0, x1, y1 = board.extent_m
    corners = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
    corners = corners - _centre(board)
    T = np.zeros((len(fills), 3))
    T[:, 2] = np.sqrt(fx * fy * bw * bh / (fills * w * h))
    rotated = np.einsum("cij,kj->cki", R, corners)  # (C, 4, 3)
    for _ in range(2):  # a lateral shift changes the perspective a little: place twice
        cam = rotated + T[:, None, :]
        u = fx * cam[..., 0] / cam[..., 2] + cx
        v = fy * cam[..., 1] / cam[..., 2] + cy
        du = _shift(u.min(axis=1), u.max(axis=1), anchors[:, 0], w)
        dv = _shift(v.min(axis=1), v.max(axis=1), anchors[:, 1], h)
        T = T + np.stack([du * T[:, 2] / fx, dv * T[:, 2] / fy, np.zeros(len(T))], axis=1)
    return T


def _shift(lo: np.ndarray, hi: np.ndarray, anchor: np.ndarray, size: int) -> np.ndarray:
    """Pixels to move [lo, hi] so it touches the image side ``anchor`` selects (0 start,
    1 end, between: proportionally), a small margin inside."""
    m = MARGIN * size
    start = m - lo
    end = (size - 1 - m) - hi
    return (1.0 - anchor) * start + anchor * end


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
    points, weight = _board_points(views, board)
    if weighted:
        weight *= float(np.median(np.concatenate([point_weights(v) for v in views])))
    cam = solution_camera(sol, image_size)
    r_max = _field_radius(cam)
    typical = _typical_depth(views, sol, board)
    cands = _candidates(sol, board, image_size)
    fills = _visible_fills(board, cands.R, cands.T, cam, r_max)
    cands = cands.subset((fills >= MIN_FILL) & (fills <= MAX_FILL))
    infos, ok = _views_information(points, _centre(board), cands, sol, groups, image_size,
                                   r_max)
    cands = cands.subset(ok)
    if len(cands.T) == 0:
        return None
    total = info[None] + infos[ok] * weight
    try:
        covs = np.linalg.inv(total) * sigma ** 2
    except np.linalg.LinAlgError:
        return None
    rms = np.sqrt(np.maximum(np.einsum("cij,ji->c", covs, grid_M) / n_grid, 0.0))
    k = int(np.argmin(rms))
    anchor = (float(cands.anchors[k, 0]), float(cands.anchors[k, 1]))
    direction, tilt = int(cands.direction[k]), float(cands.tilt_deg[k])
    rvec, tvec = cands.rvecs[k].copy(), cands.T[k] - cands.R[k] @ _centre(board)
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


def _centre(board: Board) -> np.ndarray:
    x0, y0, x1, y1 = board.extent_m
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])


@dataclass(frozen=True)
class _Candidates:
    """C candidate poses: anchors (C, 2) image fractions, fills (C,), tilt direction index
    (C,) into TILT_DIRECTIONS and tilt (C,) deg, R_cam_board (C, 3, 3) and its Rodrigues
    vector (C, 3), the board centre's camera-frame position T (C, 3) metres."""

    anchors: np.ndarray
    fills: np.ndarray
    direction: np.ndarray
    tilt_deg: np.ndarray
    R: np.ndarray
    rvecs: np.ndarray
    T: np.ndarray

    def subset(self, keep: np.ndarray) -> _Candidates:
        return _Candidates(self.anchors[keep], self.fills[keep], self.direction[keep],
                           self.tilt_deg[keep], self.R[keep], self.rvecs[keep], self.T[keep])


def _candidates(sol: Solution, board: Board, image_size: tuple[int, int]) -> _Candidates:
    """Every candidate pose: each region, fill and tilt (facing, or each angle of
    TILTS_DEG towards each of the TILT_DIRECTIONS)."""
    tilts = [(0, 0.0)] + [(k, t) for t in TILTS_DEG for k in range(len(TILT_DIRECTIONS))]
    rotations = np.stack([_tilt_rotation(45.0 * k, t) for k, t in tilts])
    rvecs = np.stack([cv2.Rodrigues(R)[0].ravel() for R in rotations])
    combos = [(a, f, i) for a in REGIONS for f in FILLS for i in range(len(tilts))]
    anchors = np.array([a for a, _, _ in combos], np.float64)
    fills = np.array([f for _, f, _ in combos], np.float64)
    which = np.array([i for _, _, i in combos])
    R = rotations[which]
    T = _place(np.asarray(sol.camera_matrix, np.float64), board, image_size, anchors, fills, R)
    return _Candidates(anchors, fills, np.array([tilts[i][0] for i in which]),
                       np.array([tilts[i][1] for i in which]), R, rvecs[which], T)


def _board_points(views: Sequence[ViewPoints], board: Board) -> tuple[np.ndarray, float]:
    """The board points a new view would give in the current points mode, at most
    :data:`MAX_POINTS` of them spread over the board: ((M, 3) metres, the number of all
    points over M, the factor their information is scaled by)."""
    if board.has_points:
        pts = board.object_points()
    elif views[0].marker_corners_px is not None:
        pts = board.object_centers()
    else:
        pts = board.object_corners().reshape(-1, 3)
    stride = max(1, math.ceil(len(pts) / MAX_POINTS))
    return pts[::stride], len(pts) / len(pts[::stride])


def _views_information(points: np.ndarray, centre: np.ndarray, cands: _Candidates,
                       sol: Solution, groups: list[tuple[int, ...]],
                       image_size: tuple[int, int],
                       r_max: float) -> tuple[np.ndarray, np.ndarray]:
    """The free intrinsics' information each candidate's view would bring (unit weight), its
    own pose eliminated: A^T A - A^T B (B^T B)^-1 B^T A over the points (M, 3) that fall
    inside the image (``centre``: (3,) the board point the candidates' T place).

    Returns:
        ((C, p, p) information, (C,) bool: at least 6 points in view).
    """
    p = len(groups)
    w, h = image_size
    C, M = len(cands.T), len(points)
    if C == 0:
        return np.zeros((0, p, p)), np.zeros(0, bool)
    cam = np.einsum("cij,mj->cmi", cands.R, points - centre) + cands.T[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.hypot(cam[..., 0], cam[..., 1]) / cam[..., 2]
    tvecs = cands.T - cands.R @ centre
    jac = [project_with_jacobian(points, cands.rvecs[c], tvecs[c], sol.camera_matrix,
                                 sol.dist_coeffs, sol.model) for c in range(C)]
    px = np.stack([j[0] for j in jac])
    A_full = np.stack([j[1] for j in jac])
    B_full = np.stack([j[2] for j in jac])
    n_all = A_full.shape[2]
    seen = ((cam[..., 2] > 1e-3) & (r <= r_max) & (px[..., 0] >= 0) & (px[..., 0] <= w - 1)
            & (px[..., 1] >= 0) & (px[..., 1] <= h - 1))
    ok = seen.sum(axis=1) >= 6
    rows = np.repeat(seen & ok[:, None], 2, axis=1)[..., None]
    A_free = free_jacobian(A_full.reshape(C * 2 * M, n_all), groups).reshape(C, 2 * M, p)
    A_all = np.where(rows, A_free, 0.0)
    B_all = np.where(rows, B_full, 0.0)
    At = np.swapaxes(A_all, 1, 2)
    AtA, AtB = At @ A_all, At @ B_all
    BtB = np.swapaxes(B_all, 1, 2) @ B_all
    BtB[~ok] = np.eye(6)
    try:
        S = AtB @ np.linalg.solve(BtB, np.swapaxes(AtB, 1, 2))
    except np.linalg.LinAlgError:
        return np.zeros((C, p, p)), np.zeros(C, bool)
    return AtA - S, ok


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
    c = _centre(board)
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
    edge = np.hstack([_outline_points(board, 2), np.zeros((8, 1))]) - _centre(board)
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
