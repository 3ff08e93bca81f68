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
from typing import Protocol

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.homography import apply_h, homographies

__all__ = ["MarkerGrowth", "compensate", "marker_growth", "neighbourhood_shift_px",
           "remove_view_shift", "robust_shift_px"]

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


# scatter of a clipped frame's side offsets about their block's median up to which its
# edges are trusted as fitted, px: between the scatter of good censored fits and of poor
# ones on bench.exposure's frames
_EDGE_SCATTER_PX = 0.04
# a side's offset is smoothed over the markers up to this many cells away (5 x 5 block)
_SMOOTH_CELLS = 2


def _outward_normals(quads: np.ndarray) -> np.ndarray:
    """(N, 4, 2) unit normals of the sides of quads (N, 4, 2), side i from corner i to
    i + 1, pointing away from the quad's centre (sides.side_frames' normals, rounded
    differently)."""
    nxt = np.roll(quads, -1, axis=1)
    tangent = nxt - quads
    normal = np.stack([tangent[..., 1], -tangent[..., 0]], axis=-1)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    centre = quads.mean(axis=1, keepdims=True)
    normal *= np.sign(np.sum((0.5 * (quads + nxt) - centre) * normal, axis=-1, keepdims=True))
    return normal


def neighbourhood_corners(ids: np.ndarray, corners_px: np.ndarray, centers_px: np.ndarray,
                          board: Board, radius: int = 1) -> np.ndarray:
    """Each marker's printed corners placed by the centres around it, pixels.

    The centres of the marker and of its neighbours in the 3 x 3 block of the grid (at
    least 5 of the 9) give a homography board -> image (least squares) that places the
    marker's printed corners. The centres do not move with the edges.

    Args:
        ids: (N,) marker ids on ``board``.
        corners_px: (N, 4, 2) corners, pixels, board order (they set each block's scale).
        centers_px: (N, 2) centres, pixels.

    Returns:
        (N, 4, 2) corners, pixels; NaN for a marker with fewer than 5 centres in its block.
    """
    n = len(ids)
    predicted = np.full((n, 4, 2), np.nan)
    if n == 0:
        return predicted
    k = np.asarray(ids) - board.first_id
    row, col = np.divmod(k, board.cols)
    r = radius
    grid = np.full((board.rows + 2 * r, board.cols + 2 * r), -1)
    grid[row + r, col + r] = np.arange(n)
    centers_px = np.asarray(centers_px, float)
    corners_px = np.asarray(corners_px, float)
    # per marker: image coordinates relative to its own centre, in units of its side
    scale = np.linalg.norm(np.roll(corners_px, -1, axis=1) - corners_px, axis=2).mean(axis=1)
    scale = np.where(scale > 0, scale, 1.0)
    rows = []
    steps = range(-r, r + 1)
    present = np.zeros((n, len(steps) ** 2), bool)
    for m, (dr, dc) in enumerate((a, b) for a in steps for b in steps):
        j = grid[row + r + dr, col + r + dc]
        present[:, m] = j >= 0
        uv = (centers_px[np.maximum(j, 0)] - centers_px) / scale[:, None]
        uv[j < 0] = 0.0
        X, Y = float(dc), float(dr)     # board units: one pitch; x along cols, y along rows
        zero, one = np.zeros(n), np.ones(n)
        u, v = uv[:, 0], uv[:, 1]
        rows.append(np.stack([X * one, Y * one, one, zero, zero, zero, -u * X, -u * Y, -u], 1)
                    * present[:, m, None])
        rows.append(np.stack([zero, zero, zero, X * one, Y * one, one, -v * X, -v * Y, -v], 1)
                    * present[:, m, None])
    A = np.stack(rows, axis=1)                         # (N, 2 B, 9), B cells in the block
    ok = present.sum(axis=1) >= (2 * r + 1) ** 2 // 2 + 1
    if not ok.any():
        return predicted
    H = np.linalg.svd(A[ok])[2][:, -1, :].reshape(-1, 3, 3)
    h = 0.5 * board.marker_length / board.pitch
    square = np.array([[-h, -h], [h, -h], [h, h], [-h, h]])
    p = apply_h(H, np.broadcast_to(square, (len(H), 4, 2)).copy())
    predicted[ok] = p * scale[ok, None, None] + centers_px[ok, None, :]
    return predicted


def side_offsets_px(corners_px: np.ndarray, predicted_px: np.ndarray) -> np.ndarray:
    """(N, 4) offset of each observed side from the predicted one along its outward
    normal (side i from corner i to i + 1), pixels: the mean of its two corners' offsets."""
    normal = _outward_normals(predicted_px)
    err = corners_px - predicted_px
    return 0.5 * (np.sum(err * normal, axis=-1)
                  + np.sum(np.roll(err, -1, axis=1) * normal, axis=-1))


def neighbourhood_shift_px(ids: np.ndarray, corners_px: np.ndarray, centers_px: np.ndarray,
                           board: Board) -> np.ndarray:
    """Each marker's edge shift read against the centres around it, pixels (outward positive).

    :func:`neighbourhood_corners` places the marker's printed corners from the centres
    of its 3 x 3 block; the mean over the four sides of the observed sides' offsets
    along their outward normals is the shift. The corners are interpolated between the
    centres rather than a neighbour extrapolated from the marker's own corners, so corner
    noise is not magnified.

    Args:
        ids: (N,) marker ids on ``board``.
        corners_px: (N, 4, 2) corners, pixels, board order.
        centers_px: (N, 2) centres, pixels.

    Returns:
        (N,) shift, pixels; NaN for a marker with fewer than 5 centres in its block.
    """
    if len(ids) == 0:
        return np.zeros(0)
    predicted = neighbourhood_corners(ids, corners_px, centers_px, board)
    return side_offsets_px(np.asarray(corners_px, float), predicted).mean(axis=1)


def robust_shift_px(d: np.ndarray) -> tuple[float, float]:
    """A robust mean of per-marker shifts ``d`` (NaN ignored) and its 1-sigma, pixels
    (inf with fewer than 4 markers)."""
    d = np.asarray(d, float)
    d = d[np.isfinite(d)]
    if len(d) < 4:
        return 0.0, float("inf")
    med = float(np.median(d))
    mad = 1.4826 * float(np.median(np.abs(d - med)))
    good = np.abs(d - med) <= max(4.0 * mad, 0.02)
    return float(np.mean(d[good])), float(np.std(d[good]) / np.sqrt(max(good.sum() - 1, 1)))


def compensate(corners_px: np.ndarray, shift_px: float) -> np.ndarray:
    """(N, 4, 2) corners with the edge shift ``shift_px`` (outward positive) removed.

    Every side's line moves by ``shift_px`` along its own normal, inward for a positive
    shift, and adjacent lines are intersected again: exactly the shift
    :func:`neighbourhood_shift_px` measures, on every side of a tilted marker alike. A
    quad with a corner that would move by more than 4 shifts (sharper than about 30
    degrees: degenerate) is left as it is.
    """
    q = np.asarray(corners_px, dtype=np.float64)
    if len(q) == 0 or shift_px == 0.0:
        return q
    out = compensate_sides(q, np.full(q.shape[:2], float(shift_px)))
    # a corner sharper than about 30 degrees would move more than 4 shifts: a quad that
    # degenerated (e.g. far out in a fisheye's undistorted coordinates) keeps its corners
    moved = np.linalg.norm(out - q, axis=-1)
    bad = ~(moved <= 4.0 * abs(shift_px)).all(axis=1)
    out[bad] = q[bad]
    return out


def compensate_sides(quads: np.ndarray, shift_px: np.ndarray) -> np.ndarray:
    """(N, 4, 2) quads with each side moved inward by its own ``shift_px`` (N, 4)
    (outward positive; side i from corner i to i + 1) and adjacent sides intersected."""
    q = np.asarray(quads, dtype=np.float64)
    normal = _outward_normals(q)
    # side i runs from corner i to i+1: n_i . x = n_i . q_i - shift
    level = np.sum(normal * q, axis=-1) - shift_px
    prev_n, prev_c = np.roll(normal, 1, axis=1), np.roll(level, 1, axis=1)
    # corner i is where side i-1 and side i meet
    det = prev_n[..., 0] * normal[..., 1] - prev_n[..., 1] * normal[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        x = (prev_c * normal[..., 1] - level * prev_n[..., 1]) / det
        y = (prev_n[..., 0] * level - normal[..., 0] * prev_c) / det
    return np.stack([x, y], axis=-1)


def toward_neighbourhood(ids: np.ndarray, raw_px: np.ndarray, corners_px: np.ndarray,
                         centers_px: np.ndarray, board: Board) -> np.ndarray:
    """A clipped frame's corners moved toward sides placed by the neighbours, when its
    edges scatter.

    Once the paper clips far, each side's fit carries its own shift (how much of its
    transition is left unclipped, how far blooming ate into it), which one shift per view
    cannot remove. Each side's offset along its normal from the side placed by the centres
    of its marker's 3 x 3 block (:func:`neighbourhood_corners`, :func:`side_offsets_px`)
    is replaced by the median of that side's offsets over the markers of the block: the
    placed sides' own error (the interpolation in a distorted image) varies smoothly over
    the image and stays, the scatter of single edges is averaged down. The scatter of the
    offsets about those medians (robust, over the view) measures the edges' noise; the
    corners are averaged with the smoothed ones with weight ``1 - (s0 / scatter)^2``
    (none below ``s0`` = :data:`_EDGE_SCATTER_PX`).

    Args:
        ids: (N,) marker ids on ``board``.
        raw_px: (N, 4, 2) the fitted corners, pixels.
        corners_px: (N, 4, 2) the same with the view's shift removed, pixels.
        centers_px: (N, 2) centres, pixels.

    Returns:
        (N, 4, 2) corners, pixels (``corners_px`` where fewer than 5 centres place a
        marker's corners, or the view has fewer than 4 such markers).
    """
    out = np.array(corners_px, float)
    raw = np.asarray(raw_px, float)
    placed = neighbourhood_corners(ids, raw, centers_px, board)
    have = np.isfinite(placed).all(axis=(1, 2))
    if have.sum() < 4:
        return out
    off = side_offsets_px(raw, placed)
    k = np.asarray(ids) - board.first_id
    row, col = np.divmod(k, board.cols)
    block = ((np.abs(row[:, None] - row[None]) <= _SMOOTH_CELLS)
             & (np.abs(col[:, None] - col[None]) <= _SMOOTH_CELLS))
    smooth = np.full((len(ids), 4), np.nan)
    for m in np.flatnonzero(have):
        smooth[m] = np.median(off[block[m] & have], axis=0)
    r = (off - smooth)[have]
    scatter = 1.4826 * float(np.median(np.abs(r - np.median(r))))
    w = max(0.0, 1.0 - (_EDGE_SCATTER_PX / max(scatter, 1e-9)) ** 2)
    if w == 0.0:
        return out
    # the placed sides moved out by the smoothed offsets, adjacent ones intersected, and
    # the view's shift removed as from the fitted corners
    moved = compensate_sides(placed[have], -smooth[have])
    out[have] = (1.0 - w) * out[have] + w * (moved + out[have] - raw[have])
    return out


class PixelLens(Protocol):
    """A lens as the shift removal uses it: image pixels (N, 2) <-> undistorted pixels (N, 2)."""

    def undistort(self, pts_px: np.ndarray) -> np.ndarray: ...

    def distort(self, pts_px: np.ndarray) -> np.ndarray: ...


# a view's edge shift is removed only beyond this over the markers read plus 2 sigma, px:
# the shift read from the centres errs by more than its sigma in views of few markers
_SHIFT_ERROR_PX = 0.3


def remove_view_shift(corners: np.ndarray, centers: np.ndarray, ids: np.ndarray, board: Board,
                      inverted: np.ndarray, lens: PixelLens | None, *,
                      place_sides: bool = False) -> tuple[np.ndarray, float]:
    """The corners with the view's edge shift removed, and the shift (NaN: unknown), pixels.

    Measured and removed in undistorted pixels when a lens is known, so the lens's change
    of scale between neighbours does not read as a shift.

    Args:
        corners: (N, 4, 2) corners, pixels, board order.
        centers: (N, 2) centres, pixels.
        ids: (N,) marker ids on ``board``.
        inverted: (N,) bool, markers printed white on black (each polarity has its own shift;
            the one returned is the black ones').
        lens: optional lens of the image.
        place_sides: a far over-exposed frame: its corners are also moved toward the sides
            its neighbours place (:func:`toward_neighbourhood`).
    """
    m = len(ids)
    q, c = corners, centers
    if lens is not None and m:
        q = lens.undistort(corners.reshape(-1, 2)).reshape(m, 4, 2)
        c = lens.undistort(centers)
    # each marker's shift against the centres around it (they do not move with it)
    marker_shift = neighbourhood_shift_px(ids, q, c, board)
    # light spreading into dark grows a white-bordered marker and shrinks a black one:
    # on a mixed board each polarity has its own shift (reported: the black ones')
    shift, largest = float("nan"), 0.0
    q_u, q = q, q.copy()
    for group in (~inverted, inverted):
        if not group.any():
            continue
        d, d_sd = robust_shift_px(marker_shift[group])
        if not np.isfinite(d_sd):
            continue
        n_read = int(np.isfinite(marker_shift[group]).sum())
        if abs(d) <= _SHIFT_ERROR_PX / n_read + 2.0 * d_sd:
            d = 0.0     # not told apart from no shift: removing it would add error
        # every side moves back along its normal (the centres were measured already)
        q[group] = compensate(q[group], d)
        largest = max(largest, abs(d))
        if not np.isfinite(shift):
            shift = d
    if not np.isfinite(shift):
        return corners, float("nan")
    if lens is not None:
        # the move, mapped back (the round trip of a point far out in a strong lens
        # need not return it exactly: only the difference is taken)
        moved = lens.distort(q.reshape(-1, 2)) - lens.distort(q_u.reshape(-1, 2))
        q = corners + moved.reshape(m, 4, 2)
        # a move the lens magnified beyond any shift's size is not one (a fold)
        wild = ~(np.linalg.norm(q - corners, axis=-1) <= 4.0 * largest + 0.05).all(axis=1)
        q[wild] = corners[wild]
    if place_sides:
        q = toward_neighbourhood(ids, corners, q, centers, board)
    return q, shift
