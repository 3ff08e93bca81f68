"""The holdable board poses :func:`~artcal_ros.core.live.guidance.next_pose` chooses from,
and the information about the free intrinsics each one's view would bring.

Candidates are poses a person can hold: the board facing the camera or tilted 20, 35 or 50
degrees towards one of eight directions, placed over the image's centre, its four edges or
its four corners, at distances where it would cover 25-150 % of the image facing the
camera; those whose visible part covers 15-85 % of the image are kept (so a tilted board,
foreshortened, may come closer than a facing one). "Tilted left" means the board's face
turned towards the image's left: its left edge farther from the camera than its right.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.model import free_jacobian, project_with_jacobian
from artcal_ros.core.calibrate.solve import Solution, ViewPoints

# Distances: the share of the image area the board would cover facing the camera (above 1:
# closer than a facing board fits; only tilted boards keep their visible part within limits).
FILLS = (0.25, 0.45, 0.65, 0.8, 1.0, 1.25, 1.5)
TILTS_DEG = (20.0, 35.0, 50.0)
TILT_DIRECTIONS = ("right", "down-right", "down", "down-left", "left", "up-left", "up",
                   "up-right")  # every 45 degrees, image x right, y down
# (anchor x, anchor y) as fractions of the image -> the region's name
REGIONS = {(0.0, 0.0): "top-left corner", (0.5, 0.0): "top edge", (1.0, 0.0): "top-right corner",
           (0.0, 0.5): "left edge", (0.5, 0.5): "centre", (1.0, 0.5): "right edge",
           (0.0, 1.0): "bottom-left corner", (0.5, 1.0): "bottom edge",
           (1.0, 1.0): "bottom-right corner"}
MAX_POINTS = 100  # board points a candidate's information is computed from (scaled to all)
MARGIN = 0.02     # of the image size, between a placed board and the image border


def board_centre(board: Board) -> np.ndarray:
    """(3,) the middle of the board's extent, board frame, metres."""
    x0, y0, x1, y1 = board.extent_m
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])


def tilt_rotation(direction_deg: float, tilt_deg: float, roll_deg: float = 0.0) -> np.ndarray:
    """(3, 3) R_cam_board of a board rolled by ``roll_deg`` about its normal, then turned
    by ``tilt_deg`` so that its side towards image direction ``direction_deg`` recedes."""
    phi, tilt = math.radians(direction_deg), math.radians(tilt_deg)
    # The axis in the image plane about which the side towards phi turns away (+z).
    axis = np.array([math.sin(phi), -math.cos(phi), 0.0])
    return np.asarray(cv2.Rodrigues((axis * tilt).reshape(3, 1))[0]
                      @ cv2.Rodrigues(np.array([0.0, 0.0, math.radians(roll_deg)]))[0])


def place(K: np.ndarray, board: Board, image_size: tuple[int, int], anchors: np.ndarray,
          fills: np.ndarray, R: np.ndarray) -> np.ndarray:
    """(C, 3) camera-frame position of the board's centre for C placements (anchors (C, 2),
    fills (C,), orientations R_cam_board (C, 3, 3)), as
    :func:`~artcal_ros.core.live.guidance.holdable_pose` places it."""
    w, h = image_size
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    bw, bh = board.size_m
    x0, y0, x1, y1 = board.extent_m
    corners = np.array([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y1, 0.0], [x0, y1, 0.0]])
    corners = corners - board_centre(board)
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


@dataclass(frozen=True)
class Candidates:
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

    def subset(self, keep: np.ndarray) -> Candidates:
        return Candidates(self.anchors[keep], self.fills[keep], self.direction[keep],
                          self.tilt_deg[keep], self.R[keep], self.rvecs[keep], self.T[keep])


def candidates(sol: Solution, board: Board, image_size: tuple[int, int]) -> Candidates:
    """Every candidate pose: each region, fill and tilt (facing, or each angle of
    TILTS_DEG towards each of the TILT_DIRECTIONS)."""
    tilts = [(0, 0.0)] + [(k, t) for t in TILTS_DEG for k in range(len(TILT_DIRECTIONS))]
    rotations = np.stack([tilt_rotation(45.0 * k, t) for k, t in tilts])
    rvecs = np.stack([cv2.Rodrigues(R)[0].ravel() for R in rotations])
    combos = [(a, f, i) for a in REGIONS for f in FILLS for i in range(len(tilts))]
    anchors = np.array([a for a, _, _ in combos], np.float64)
    fills = np.array([f for _, f, _ in combos], np.float64)
    which = np.array([i for _, _, i in combos])
    R = rotations[which]
    T = place(np.asarray(sol.camera_matrix, np.float64), board, image_size, anchors, fills, R)
    return Candidates(anchors, fills, np.array([tilts[i][0] for i in which]),
                      np.array([tilts[i][1] for i in which]), R, rvecs[which], T)


def board_points(views: Sequence[ViewPoints], board: Board) -> tuple[np.ndarray, float]:
    """The board points a new view would give in the current points mode, at most
    :data:`MAX_POINTS` of them spread over the board: ((M, 3) metres, the factor their
    information is scaled by: the number of all points over M)."""
    if board.has_points:
        pts = board.object_points()
    elif views[0].marker_corners_px is not None:
        pts = board.object_centers()
    else:
        pts = board.object_corners().reshape(-1, 3)
    stride = max(1, math.ceil(len(pts) / MAX_POINTS))
    return pts[::stride], len(pts) / len(pts[::stride])


def views_information(points: np.ndarray, centre: np.ndarray, cands: Candidates,
                      sol: Solution, groups: list[tuple[int, ...]], image_size: tuple[int, int],
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
