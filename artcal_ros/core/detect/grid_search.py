"""Markers looked for where the board's layout puts them, in over-exposed frames.

Once the paper clips far enough, blooming eats through the thin borders of small markers
and the quad finder, which needs a closed dark contour, finds only a few of them. The
markers it did find and that passed every check pin the board down locally: a homography
from the board to the image, fitted to the centres of the verified markers within two
cells of a missing one (at least four; with only three, to their corners; never all in
one row or column), predicts its quad. A predicted quad is kept only when its module
means, read there, correlate best with the expected id's pattern in its expected
orientation among every id and rotation of the board (the patterns as a clipped sensor
sees them, :func:`~artcal_ros.core.detect.patterns.clipped_patterns`), by a clear margin.
The quads kept then go through the same edge fit as the quad finder's, and the markers
found predict more, round by round (:func:`grow`).

Only the markers of a marker grid are predicted (their layout is one regular grid).
See docs/tone.md, "Clipped frames".
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.centers import diagonal_centers
from artcal_ros.core.detect.decode import PatternTable, pattern_correlations
from artcal_ros.core.detect.edges import EdgeFit, same_edges
from artcal_ros.core.detect.sampling import cell_means, module_grid
from artcal_ros.core.detect.verify import neighbour_support
from artcal_ros.core.homography import module_homographies, shortest_sides

__all__ = ["grow", "matches_expected", "predicted_quads"]

# cells (Chebyshev distance on the grid) from which verified markers predict a missing one
_REACH = 2
# least correlation with the expected pattern, and least margin over every other id and
# rotation, for a predicted quad to be fitted
_MIN_CORR = 0.6
_MARGIN = 0.1


def predicted_quads(ids: np.ndarray, corners_px: np.ndarray, board: Board,
                    image_wh: tuple[int, int], min_side_px: float, clear_px: float = 2.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Quads of the board's markers not in ``ids``, predicted from the verified ones around.

    Args:
        ids: (N,) verified marker ids.
        corners_px: (N, 4, 2) their corners TL, TR, BR, BL, pixels.
        board: the calibration board (a marker grid).
        image_wh: (width, height) of the image, pixels.
        min_side_px: a predicted quad with a shorter side is not returned.
        clear_px: a predicted quad must lie this far inside the image, pixels.

    Returns:
        quads (P, 4, 2) TL, TR, BR, BL in pixels and their ids (P,).
    """
    if len(ids) < 3:
        return np.zeros((0, 4, 2)), np.zeros(0, np.int64)
    rc = board.marker_cells(ids)
    obj = board.object_corners(ids)[:, :, :2]
    # the centres do not move with the edges: with enough of them around, the homography
    # is fitted to them alone
    centres = diagonal_centers(corners_px, np.zeros((len(ids), 4)), None)[0]
    obj_centres = obj.mean(axis=1)
    missing = board.ids[~np.isin(board.ids, ids)]
    mrc = board.marker_cells(missing)
    mobj = board.object_corners(missing)[:, :, :2]
    w, h = image_wh
    quads, out_ids = [], []
    for k in range(len(missing)):
        near = np.abs(rc - mrc[k]).max(axis=1) <= _REACH
        if near.sum() < 3 or len(np.unique(rc[near, 0])) < 2 or len(np.unique(rc[near, 1])) < 2:
            continue
        if near.sum() >= 4:
            src, dst = obj_centres[near], centres[near]
        else:
            src, dst = obj[near].reshape(-1, 2), corners_px[near].reshape(-1, 2)
        H, _ = cv2.findHomography(src, dst, 0)
        if H is None:
            continue
        q = cv2.perspectiveTransform(mobj[k][None], H)[0]
        x, y = q[:, 0], q[:, 1]
        if (x.min() < clear_px or y.min() < clear_px or x.max() > w - 1 - clear_px
                or y.max() > h - 1 - clear_px):
            continue
        quads.append(q)
        out_ids.append(missing[k])
    if not quads:
        return np.zeros((0, 4, 2)), np.zeros(0, np.int64)
    qa = np.asarray(quads, np.float64)
    ia = np.asarray(out_ids, np.int64)
    big = shortest_sides(qa) >= min_side_px
    return qa[big], ia[big]


def matches_expected(lin: np.ndarray, quads: np.ndarray, ids: np.ndarray,
                     table: PatternTable) -> np.ndarray:
    """(P,) bool: the module means at each quad correlate best with its own id, unrotated.

    The correlation (centred, normalised) of the quad's module means with the expected
    id's pattern in the given corner order, at the best of the table's blur and clip
    levels, must reach :data:`_MIN_CORR` and exceed that of every other id in every
    rotation, and of the expected id rotated, by :data:`_MARGIN`.

    Args:
        lin: (H, W) linear intensity image.
        quads: (P, 4, 2) predicted corners TL, TR, BR, BL, pixels.
        ids: (P,) the ids expected there.
        table: the board's patterns (as a clipped sensor sees them).
    """
    P = len(ids)
    if P == 0:
        return np.zeros(0, bool)
    n = table.n
    H = module_homographies(quads, n - 2)
    vals = cell_means(lin, H, module_grid(n, 0.22)).reshape(P, n, n)
    own = np.full(P, -1.0)
    other = np.full(P, -1.0)
    # the table lists the board's ids in order first (then, for any polarity, inverted)
    index = np.asarray(ids, np.int64) - int(table.ids[0])
    for roll in range(4):
        corr = pattern_correlations(vals, table, roll)
        if roll == 0:
            own = corr[np.arange(P), index]
            corr[np.arange(P), index] = -1.0
        other = np.maximum(other, corr.max(axis=1))
    return np.asarray((own >= _MIN_CORR) & (own - other >= _MARGIN))


def grow(lin: np.ndarray, ids: np.ndarray, corners_px: np.ndarray, sigma_px: np.ndarray,
         board: Board, table: PatternTable, refine: Callable[[np.ndarray, np.ndarray], EdgeFit],
         *, min_side_px: float, tolerance: float, rounds: int = 12,
         hints: tuple[np.ndarray, np.ndarray] | None = None
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The verified markers plus those found where they predict more, round by round.

    Each round predicts the missing markers' quads from the markers known so far
    (:func:`predicted_quads`), keeps those whose code reads as expected there
    (:func:`matches_expected`), refines them (``refine``), and keeps the refined quads
    that stayed on the predicted edges, still read as expected there, and pass the
    neighbour check (:func:`~artcal_ros.core.detect.verify.neighbour_support`).

    Args:
        lin: (H, W) linear intensity image.
        ids, corners_px, sigma_px: (N,), (N, 4, 2), (N, 4): the verified markers.
        board: the calibration board (a marker grid).
        table: the board's patterns as a clipped sensor sees them.
        refine: the edge fit of quads (Q, 4, 2) with ids (Q,).
        min_side_px: predicted quads with a shorter side are ignored.
        tolerance: neighbour check tolerance, marker sides.
        rounds: most rounds.
        hints: quads (K, 4, 2) and ids (K,) the checks rejected, tried in the first round
            like predicted ones.

    Returns:
        ids (M,), corners (M, 4, 2) and sigmas (M, 4), the verified markers first.
    """
    h, w = lin.shape
    for r in range(rounds):
        q, qid = predicted_quads(ids, corners_px, board, (w, h), min_side_px)
        if r == 0 and hints is not None:
            # quads the checks rejected: where the grid predicts none (too few verified
            # markers around) they are the only start
            new = ~np.isin(hints[1], qid) & ~np.isin(hints[1], ids)
            q, qid = np.concatenate([q, hints[0][new]]), np.concatenate([qid, hints[1][new]])
        good = matches_expected(lin, q, qid, table)
        q, qid = q[good], qid[good]
        if len(qid) == 0:
            break
        fit = refine(q, qid)
        keep = fit.ok & same_edges(fit.corners_px, q)
        c, s, i = fit.corners_px[keep], fit.corner_sigma_px[keep], qid[keep]
        # (the code is checked against the clipped patterns: the unclipped check,
        # code_errors, fails most markers whose code the clipping has eaten into)
        keep = matches_expected(lin, c, i, table)
        support = neighbour_support(np.concatenate([corners_px, c]), np.concatenate([ids, i]),
                                    board, tolerance)[len(ids):]
        keep &= support > 0
        if not keep.any():
            break
        ids = np.concatenate([ids, i[keep]])
        corners_px = np.concatenate([corners_px, c[keep]])
        sigma_px = np.concatenate([sigma_px, s[keep]])
    return ids, corners_px, sigma_px
