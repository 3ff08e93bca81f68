"""Edge shift: light, blur and the tone curve move every dark/light edge along its normal.

On a board of dark squares on light paper (or the reverse) a shift ``d`` of every
border edge makes each marker look ``2 d`` larger (or smaller) while the pitch
between marker centres does not change: centres are the diagonals' crossing and
opposite edges move in opposite directions. The ratio of a marker's own size to
the distance of its neighbours' centres, both read in the marker's own
homography, therefore measures ``d`` in every view (:func:`marker_growth`); the
corners are then moved back by it (:func:`compensate`).

The same ratio also measures the print: a board whose markers are smaller than
configured relative to the pitch (a wrong separation) looks like an inward edge
shift. The two differ in their units: an optical shift is a fixed number of
*pixels* in a view, a print error a fixed fraction of the *marker*, so markers
seen at different scales separate them (:mod:`artcal_ros.core.calibrate.board_check`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.homography import apply_h, homographies

__all__ = ["MarkerGrowth", "compensate", "marker_growth", "view_shift_px"]

_NEIGHBOURS = ((0, 1), (1, 0), (0, -1), (-1, 0))
# largest relative misfit of a neighbour's distance to the pitch (an edge shift of a
# pixel on a 10 px marker is 0.2)
_NEIGHBOUR_TOLERANCE = 0.25


@dataclass(frozen=True)
class MarkerGrowth:
    """Per marker of one view: how much larger than printed it looks against the pitch.

    Attributes:
        growth: (N,) relative size excess, ``P_nominal / P_measured - 1`` (NaN without
            a neighbour): 2 d / L for an edge shift d (board units), the print error's
            ``L_printed / L - 1`` otherwise.
        px_per_m: (N,) the marker's scale, pixels per metre of board.
        homography: (N, 3, 3) the marker's board-local (metres, origin its centre) ->
            image homography from its corners.
    """

    growth: np.ndarray
    px_per_m: np.ndarray
    homography: np.ndarray


def marker_growth(ids: np.ndarray, corners_px: np.ndarray, centers_px: np.ndarray,
                  board: Board) -> MarkerGrowth:
    """Each marker's apparent size against its neighbours' centres.

    Args:
        ids: (N,) marker ids on ``board``.
        corners_px: (N, 4, 2) corners, pixels, board order.
        centers_px: (N, 2) centres, pixels.
        board: the board (its layout, marker length and separation).
    """
    n = len(ids)
    half = 0.5 * board.marker_length
    square = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    if n == 0:
        return MarkerGrowth(np.zeros(0), np.zeros(0), np.zeros((0, 3, 3)))
    H = homographies(np.broadcast_to(square, (n, 4, 2)), np.asarray(corners_px, float))
    H_inv = np.linalg.inv(H)
    k = np.asarray(ids) - board.first_id
    row, col = np.divmod(k, board.cols)
    grid = np.full((board.rows + 2, board.cols + 2), -1)
    grid[row + 1, col + 1] = np.arange(n)
    pitch = board.marker_length + board.marker_separation
    own = np.einsum("nij,nj->ni", H_inv, np.c_[centers_px, np.ones(n)])
    own = own[:, :2] / own[:, 2:]
    dist_sum, count = np.zeros(n), np.zeros(n)
    for dr, dc in _NEIGHBOURS:
        j = grid[row + 1 + dr, col + 1 + dc]
        has = j >= 0
        if not has.any():
            continue
        q = np.einsum("nij,nj->ni", H_inv[has], np.c_[centers_px[j[has]], np.ones(has.sum())])
        q = q[:, :2] / q[:, 2:]
        d = np.hypot(*(q - own[has]).T)
        # a neighbour by id that is not at one pitch is not a neighbour in the print
        # (a board configured only for its ids, e.g. ChArUco markers as one long row)
        near = np.abs(d / pitch - 1.0) < _NEIGHBOUR_TOLERANCE
        idx = np.flatnonzero(has)[near]
        dist_sum[idx] += d[near]
        count[idx] += 1
    with np.errstate(invalid="ignore", divide="ignore"):
        growth = pitch / (dist_sum / count) - 1.0
    sides = np.linalg.norm(np.roll(corners_px, -1, axis=1) - corners_px, axis=2).mean(axis=1)
    px_per_m = sides / (board.marker_length * (1.0 + np.nan_to_num(growth)))
    return MarkerGrowth(growth, px_per_m, H)


def view_shift_px(g: MarkerGrowth, board: Board, *, print_growth: float = 0.0
                  ) -> tuple[float, float]:
    """The view's edge shift (outward positive) and its 1-sigma, pixels.

    Args:
        g: the view's :func:`marker_growth`.
        print_growth: the print's own growth (0: the board as configured).
    """
    d = (g.growth - print_growth) * 0.5 * board.marker_length * g.px_per_m
    d = d[np.isfinite(d)]
    if len(d) < 4:
        return 0.0, float("inf")
    med = float(np.median(d))
    mad = 1.4826 * float(np.median(np.abs(d - med)))
    good = np.abs(d - med) <= max(4.0 * mad, 0.02)
    return float(np.mean(d[good])), float(np.std(d[good]) / np.sqrt(max(good.sum() - 1, 1)))


def compensate(corners_px: np.ndarray, g: MarkerGrowth, shift_px: float,
               board: Board) -> np.ndarray:
    """(N, 4, 2) corners with the edge shift ``shift_px`` (outward positive) removed.

    Each marker's quad shrinks (grows) about its centre in its own homography, so
    the perspective of a tilted marker is kept.
    """
    n = len(corners_px)
    if n == 0 or shift_px == 0.0:
        return corners_px
    half = 0.5 * board.marker_length
    # the observed quad is a square of half-side half + d_b (board units)
    d_b = shift_px / g.px_per_m
    scale = half / (half + d_b)
    square = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    pts = square[None, :, :] * scale[:, None, None]
    return apply_h(g.homography, pts)
