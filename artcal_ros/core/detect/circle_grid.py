"""A circle grid's blobs as OpenCV finds them, put in the board's order and checked.

- :func:`find_circle_grid`: OpenCV's ``findCirclesGrid`` (its grid search, then its
  clustering search) with a blob detector for small and large circles alike.
- :func:`orient_grid`: of the grid's flips and turns, the orders that fit a homography of
  the board's object points with the print facing the camera; of those (a symmetric grid
  and an asymmetric one with an even number of rows look the same turned by a half turn, a
  square symmetric grid by a quarter turn; an asymmetric grid with an odd number of rows
  fits one order only) the one whose point 0 is nearest the image's top-left corner.
- :func:`misplaced`: blobs off the place their grid neighbours predict.
- :func:`grid_continues`: circles where the pattern's next row or column would be (a print
  larger than the board configured).
"""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.lens import Lens
from artcal_ros.core.homography import neighbour_misfit


def _blob_detectors() -> tuple[cv2.SimpleBlobDetector, ...]:
    """OpenCV's default blob detector, then one for small far and large near circles too
    (OpenCV's area range is 25 - 5000 px; the wider one also takes more clutter, which
    can spoil a grid the default finds)."""
    wide = cv2.SimpleBlobDetector.Params()
    wide.minArea = 8.0
    wide.maxArea = 1e6
    wide.minDistBetweenBlobs = 3.0
    return (cv2.SimpleBlobDetector.create(), cv2.SimpleBlobDetector.create(wide))


def find_circle_grid(gray8: np.ndarray, board: Board) -> np.ndarray | None:
    """(rows, cols, 2) float64 OpenCV's grid of blob centres in its own order, or None."""
    flags = (cv2.CALIB_CB_ASYMMETRIC_GRID if board.board_type == "acircles"
             else cv2.CALIB_CB_SYMMETRIC_GRID)
    size = (board.cols, board.rows)
    for detector in _blob_detectors():
        # the default grid search fails on steep views that clustering finds, and the reverse
        for extra in (0, cv2.CALIB_CB_CLUSTERING):
            found, centres = cv2.findCirclesGrid(gray8, size, flags=flags | extra,
                                                 blobDetector=detector)
            if found and centres is not None and len(centres) == board.cols * board.rows:
                return np.asarray(centres, dtype=np.float64).reshape(board.rows, board.cols, 2)
    return None


def _orders(grid: np.ndarray) -> list[np.ndarray]:
    """The grid's re-orderings that keep its shape: flips, half turn, and on a square grid
    the transposes and quarter turns."""
    out = [grid, grid[::-1, ::-1], grid[::-1], grid[:, ::-1]]
    if grid.shape[0] == grid.shape[1]:
        t = grid.transpose(1, 0, 2)
        out += [t, t[::-1, ::-1], t[::-1], t[:, ::-1]]
    return out


def homography(board_xy: np.ndarray, image_xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares homography board (M, 2) metres -> image (M, 2) px and its RMS residual."""
    H, _ = cv2.findHomography(board_xy, image_xy, 0)
    if H is None:
        return np.eye(3), float("inf")
    p = cv2.perspectiveTransform(board_xy.reshape(-1, 1, 2), H).reshape(-1, 2)
    return H, float(np.sqrt(np.mean(np.sum((p - image_xy) ** 2, axis=1))))


def orient_grid(grid: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray] | None:
    """The grid re-ordered to the board's ids (see the module docstring) and its homography
    (board metres -> image px); None when no order fits the board."""
    obj = board.object_points()[:, :2]
    spacing_px = np.median(np.linalg.norm(np.diff(grid.reshape(-1, 2), axis=0), axis=1))
    fits = []
    for g in _orders(grid):
        H, rms = homography(obj, g.reshape(-1, 2))
        # the print faces the camera: the board's x and y axes keep their handedness
        J = H[:2, :2] - np.outer(H[:2, 2], H[2, :2])
        if np.linalg.det(J) > 0:
            fits.append((rms, g, H))
    if not fits:
        return None
    best = min(f[0] for f in fits)
    # a homography fits the true order to the lens's bending (a few px at a webcam's corner);
    # a wrong order is off by whole spacings
    if best > 0.25 * spacing_px:
        return None
    good = [f for f in fits if f[0] <= best + 0.1 * spacing_px]
    _, g, H = min(good, key=lambda f: float(f[1][0, 0].sum()))
    return g, H


def misplaced(points_px: np.ndarray, cells: np.ndarray, tolerance: float = 0.3) -> np.ndarray:
    """(n,) bool: grid points off the place their neighbours predict (a blob OpenCV put in
    the grid that is not that circle).

    Each point is predicted by an affine map of the lattice cells (n, 2) fitted to the
    points within two cells of it (itself left out); over so small a patch perspective
    and lens are nearly affine. The worst point beyond ``tolerance`` local spacings is
    flagged and left out of its neighbours' fits, and so on until none is.
    """
    out = np.zeros(len(points_px), bool)
    while True:
        misfit = np.where(out, np.nan, neighbour_misfit(points_px, cells, radius=2, use=~out))
        if not np.nan_to_num(misfit, nan=0.0).max(initial=0.0) > tolerance:
            break
        out[np.nanargmax(misfit)] = True
    return out


def border_cells(board: Board) -> tuple[np.ndarray, np.ndarray]:
    """Lattice cells one lattice step outside the grid where the pattern would have its
    next circles (on the printed margin).

    Returns:
        (cells (K, 2) int64 (row, column); side (K,) int64: 0 above, 1 below, 2 left,
        3 right of the grid).
    """
    circles = board.circles
    assert circles is not None
    cells = board.point_cells(board.point_ids)
    c0, c1 = int(cells[:, 1].min()), int(cells[:, 1].max())
    rows = np.arange(-1, board.rows + 1)
    cols = np.arange(c0 - 1, c1 + 2)
    r, c = (a.ravel() for a in np.meshgrid(rows, cols, indexing="ij"))
    beyond = (r < 0) | (r >= board.rows) | (c < c0) | (c > c1)
    corner = ((r < 0) | (r >= board.rows)) & ((c < c0) | (c > c1))
    fits = (c - r) % 2 == 0 if circles.asymmetric else np.ones_like(beyond)
    keep = beyond & ~corner & fits
    side = np.select([r < 0, r >= board.rows, c < c0], [0, 1, 2], 3)
    return np.stack([r[keep], c[keep]], axis=1).astype(np.int64), side[keep]


def grid_continues(lin: np.ndarray, board: Board, H_u: np.ndarray, lens: Lens,
                   centres_px: np.ndarray, radius_px: float) -> bool:
    """Whether the image shows circles where the pattern's next row or column would be:
    then the print is larger than the board configured (or another grid), and ids counted
    from this grid's edge would be wrong.

    Args:
        H_u: (3, 3) board metres -> straightened pixels. centres_px: (M, 2) the circles found.
        radius_px: the circles' typical radius in the image.
    """
    s = board.square_length
    obj = board.object_points()[:, :2]
    # paper between the circles: half a step diagonally (symmetric), one step across
    # (asymmetric: the empty lattice cells)
    gap = obj + (np.array([s, 0.0]) if board.board_type == "acircles" else 0.5 * s)
    x1, y1 = board.extent_m[2:]
    gap = gap[(gap[:, 0] < x1) & (gap[:, 1] < y1)]

    def image_of(board_xy: np.ndarray) -> np.ndarray:
        mapped = cv2.perspectiveTransform(board_xy.reshape(-1, 1, 2).astype(np.float64), H_u)
        return lens.distort(mapped.reshape(-1, 2))

    h, w = lin.shape
    r = max(1.0, 0.4 * radius_px)

    def level(points: np.ndarray) -> np.ndarray:
        out = np.full(len(points), np.nan)
        for k, (x, y) in enumerate(points):
            if r <= x < w - 1 - r and r <= y < h - 1 - r:
                patch = lin[int(y - r):int(y + r) + 1, int(x - r):int(x + r) + 1]
                out[k] = float(np.median(patch))
        return out

    cells, side = border_cells(board)
    seen = level(image_of(cells[:, ::-1] * s))
    dark = float(np.nanmedian(level(centres_px)))
    paper = float(np.nanmedian(level(image_of(gap))))
    # circle-dark: nearer the circles' level than the paper's. A larger print shows a
    # whole row or column of them; one dark spot (the board's edge, clutter past it, an
    # extrapolation a few pixels off near the image's corner) is not that.
    is_dark = seen < dark + 0.35 * (paper - dark)
    for k in range(4):
        visible = np.isfinite(seen[side == k])
        hits = int(is_dark[side == k].sum())
        if hits >= 2 and hits >= 0.5 * visible.sum():
            return True
    return False
