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
    if found and corners is not None and len(corners) == cols * rows:
        return np.asarray(corners, dtype=np.float64).reshape(rows, cols, 2)
    return find_small_grid(gray8, cols, rows)


# Squares of 4-6 px defeat OpenCV's finders, whose thresholding and erosion need ~7 px.
# Enlarged four times, the same finder with its quick check reads them; enlarging only the
# small regions dense with X-corners keeps that cheap and keeps the finder away from the
# rest of the image (whose marker codes it can read as a grid).
_SMALL_SQUARE_PX = 10.0     # boards with larger squares are left to the finders above
_UPSCALE = 4


def small_board_regions(gray8: np.ndarray, cols: int, rows: int
                        ) -> list[tuple[int, int, int, int]]:
    """Image regions (x0, y0, x1, y1) that may hold the whole board with small squares.

    A region is a cluster of X-corner responses (the Hessian's determinant negative: a
    saddle of the grey level) with at least 80 % of the board's inner corners, no wider or
    taller than the board could be with squares of ``_SMALL_SQUARE_PX``; the densest first,
    at most four, none mostly inside another.
    """
    smooth = cv2.GaussianBlur(gray8.astype(np.float32), (0, 0), 1.0)
    ixx = cv2.Sobel(smooth, cv2.CV_32F, 2, 0, ksize=3)
    iyy = cv2.Sobel(smooth, cv2.CV_32F, 0, 2, ksize=3)
    ixy = cv2.Sobel(smooth, cv2.CV_32F, 1, 1, ksize=3)
    response = np.asarray(ixy * ixy - ixx * iyy, dtype=np.float32)
    top = float(np.percentile(response, 99.99))
    if not top > 0:
        return []
    peaks = (response > 0.05 * top) & (response >= cv2.dilate(response, np.ones((3, 3))))
    max_side = 1.5 * _SMALL_SQUARE_PX * (max(cols, rows) + 1)
    h, w = gray8.shape
    pad = 2 * int(_SMALL_SQUARE_PX)
    found: dict[tuple[int, int, int, int], int] = {}
    # Neighbouring corners link when within `link` px; a short link keeps a board of tiny
    # squares apart from the clutter beside it, a long one holds larger squares together.
    for link in (5, 7, 9):
        linked = cv2.dilate(peaks.astype(np.uint8), np.ones((link, link), np.uint8))
        n, labels, stats, _ = cv2.connectedComponentsWithStats(linked)
        counts = np.bincount(labels[peaks], minlength=n)
        for k in np.flatnonzero(counts >= 0.8 * cols * rows):
            x, y, bw, bh = (int(v) for v in stats[k, :4])
            if k > 0 and max(bw, bh) <= max_side:
                region = (max(0, x - pad), max(0, y - pad), min(w, x + bw + pad),
                          min(h, y + bh + pad))
                found[region] = int(counts[k])
    chosen: list[tuple[int, int, int, int]] = []
    for r in sorted(found, key=lambda r: -found[r]):
        if len(chosen) < 4 and not any(_overlap(r, c) > 0.5 for c in chosen):
            chosen.append(r)
    return chosen


def _overlap(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> float:
    """Share of region ``a``'s area that region ``b`` covers."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    return max(w, 0) * max(h, 0) / max((a[2] - a[0]) * (a[3] - a[1]), 1)


def find_small_grid(gray8: np.ndarray, cols: int, rows: int) -> np.ndarray | None:
    """(rows, cols, 2) float64 grid of a board with small squares, or None.

    OpenCV's classic finder on each of ``small_board_regions`` enlarged ``_UPSCALE`` times;
    a grid is kept only when its squares alternate dark and light (``squares_alternate``).
    """
    for x0, y0, x1, y1 in small_board_regions(gray8, cols, rows):
        big = cv2.resize(gray8[y0:y1, x0:x1], None, fx=_UPSCALE, fy=_UPSCALE,
                         interpolation=cv2.INTER_CUBIC)
        found, corners = cv2.findChessboardCorners(
            big, (cols, rows), flags=_CLASSIC_FLAGS | cv2.CALIB_CB_FAST_CHECK)
        if not found or corners is None or len(corners) != cols * rows:
            continue
        # pixel centres: enlarged pixel u covers original (u + 0.5) / s - 0.5
        grid = ((np.asarray(corners, np.float64).reshape(rows, cols, 2) + 0.5) / _UPSCALE
                - 0.5 + np.array([x0, y0], np.float64))
        if squares_alternate(gray8, grid):
            return grid
    return None


def squares_alternate(gray: np.ndarray, grid: np.ndarray) -> bool:
    """True when the squares inside the grid (rows, cols, 2) alternate dark and light.

    Each square's grey level is read at its centre (a 3 x 3 box); at least 90 % of the pairs
    of side-by-side squares must differ the way a chequerboard does. A grid read into other
    squares of the image (marker codes, tiles) rarely passes.
    """
    if min(grid.shape[:2]) < 2:
        return True
    centres = 0.25 * (grid[:-1, :-1] + grid[:-1, 1:] + grid[1:, :-1] + grid[1:, 1:])
    box = cv2.blur(gray.astype(np.float32), (3, 3))
    ij = np.round(centres).astype(np.int64)
    ij[..., 0] = np.clip(ij[..., 0], 0, gray.shape[1] - 1)
    ij[..., 1] = np.clip(ij[..., 1], 0, gray.shape[0] - 1)
    level = box[ij[..., 1], ij[..., 0]].astype(np.float64)
    parity = np.where((np.add.outer(np.arange(level.shape[0]), np.arange(level.shape[1]))
                       % 2) == 0, 1.0, -1.0)
    # on a chequerboard, square minus right (or lower) neighbour has one sign on even
    # squares and the other on odd ones
    steps = np.concatenate([np.sign(parity[:, :-1] * (level[:, :-1] - level[:, 1:])).ravel(),
                            np.sign(parity[:-1] * (level[:-1] - level[1:])).ravel()])
    if steps.size == 0:
        return True
    agree = max(np.mean(steps > 0), np.mean(steps < 0))
    return bool(agree >= 0.9)


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
