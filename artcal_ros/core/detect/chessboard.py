"""Chessboard inner corners with identities: OpenCV finds the grid, the saddle fit refines it.

A chessboard has no code, so a view names its corners only when the whole grid of
``cols`` x ``rows`` inner corners is found by OpenCV's grid finders. Partial views are not
accepted: a part of a chessboard cannot be placed on the board without doubt.

Identities: the grid comes back row-major but may start at any of its four corners. The
board frame is right-handed with the printed side to the camera, so a mirrored order is
turned the right way first; then the square between corners 0, 1, cols and cols + 1 must be
black (the board's top-left square is black). When ``cols + rows`` is odd that square's
colour tells the two remaining orders apart and every id is exact. When it is even the
board looks the same turned by 180 degrees; the order is then chosen with corner 0 nearer
the image's top-left corner (as camera_calibration does), and ids are exact up to that
symmetry, which no image can resolve and a calibration does not need.
"""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.saddle import fit_saddles

_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE


def find_grid(gray8: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """(rows, cols, 2) float64 OpenCV's unrefined grid of inner corners, or None."""
    # The classic finder with its quick check takes a few ms; the sector-based one finds
    # more boards (strong distortion, blur) at ~50x the time; the classic one without the
    # quick check (which refuses squares below ~7 px) finds some small-square boards the
    # sector-based one misses.
    found, corners = cv2.findChessboardCorners(
        gray8, (cols, rows), flags=_CLASSIC_FLAGS | cv2.CALIB_CB_FAST_CHECK)
    if not found:
        found, corners = cv2.findChessboardCornersSB(gray8, (cols, rows))
    if not found:
        found, corners = cv2.findChessboardCorners(gray8, (cols, rows), flags=_CLASSIC_FLAGS)
    if not found or corners is None or len(corners) != cols * rows:
        return None
    return np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)


def grid_axes(grid: np.ndarray) -> np.ndarray:
    """(rows, cols, 2, 2) local images of one square along the grid's x and y axes.

    Central differences inside the grid, one-sided at its border.
    """
    ax = np.gradient(grid, axis=1)
    ay = np.gradient(grid, axis=0)
    return np.stack([ax, ay], axis=-1)


def _mean_in_quad(lin: np.ndarray, quad: np.ndarray) -> float:
    """Mean linear intensity over the inner half of an image quad (4, 2)."""
    c = quad.mean(axis=0)
    pts = c + 0.5 * (quad - c)
    mask = np.zeros(lin.shape, np.uint8)
    cv2.fillConvexPoly(mask, np.round(pts).astype(np.int32), 1)
    vals = lin[mask > 0]
    return float(vals.mean()) if vals.size else float("nan")


def orient_grid(grid: np.ndarray, lin: np.ndarray, board: Board) -> np.ndarray | None:
    """The grid (rows, cols, 2) re-ordered to the board's ids (see the module docstring);
    None when the squares' colours contradict the board (it is not this chessboard)."""
    e1 = grid[0, 1] - grid[0, 0]
    e2 = grid[1, 0] - grid[0, 0]
    if e1[0] * e2[1] - e1[1] * e2[0] < 0:        # mirrored: the rows run upwards
        grid = grid[::-1]
    first = _mean_in_quad(lin, np.array([grid[0, 0], grid[0, 1], grid[1, 1], grid[1, 0]]))
    second = _mean_in_quad(lin, np.array([grid[0, 1], grid[0, 2], grid[1, 2], grid[1, 1]])
                           if grid.shape[1] > 2 else
                           np.array([grid[1, 0], grid[1, 1], grid[2, 1], grid[2, 0]]))
    if not (np.isfinite(first) and np.isfinite(second)):
        return None
    first_dark = first < second
    if (board.cols + board.rows) % 2 == 1:
        # turned by 180 degrees the first square is the white one diagonally opposite
        return grid if first_dark else grid[::-1, ::-1]
    if not first_dark:
        return None
    if grid[-1, -1].sum() < grid[0, 0].sum():
        grid = grid[::-1, ::-1]
    return grid


def detect_chessboard(gray8: np.ndarray, lin: np.ndarray, board: Board
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The chessboard's inner corners in one image.

    Args:
        gray8: (H, W) uint8 contrast-stretched grey (for OpenCV's grid finder).
        lin: (H, W) float linear-light grey (for the saddle fit).
        board: a ``chessboard`` board.

    Returns:
        (point_ids (M,) int64, points_px (M, 2) float64, point_sigma_px (M,) float64); empty
        unless the whole board was found. Corners whose fit failed are left out.
    """
    none = (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0))
    grid = find_grid(gray8, board.cols, board.rows)
    if grid is None:
        return none
    grid = orient_grid(grid, lin, board)
    if grid is None:
        return none
    ids = board.point_ids
    chess = board.chess
    assert chess is not None
    fit = fit_saddles(lin, grid.reshape(-1, 2), grid_axes(grid).reshape(-1, 2, 2),
                      chess.corner_black_diagonal(ids))
    ok = fit.ok
    return ids[ok], fit.points_px[ok], fit.sigma_px[ok]
