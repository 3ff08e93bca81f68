"""A second decoder for the quads OpenCV's ArUco detector found but could not read.

Under defocus, motion blur or clipping OpenCV's per-cell Otsu threshold often
fails although the quad itself was found. Here the quad is corrected by the
~0.7 px its contour runs inside (dark border) or outside (light border) the
true border, every module is read as the
mean of 3 x 3 samples in linear intensity, thresholded halfway between the
border's level and the quiet zone's, and the 8 x 8 pattern (border included) is
compared with the board's own markers in all four rotations. Only the board's
ids can match, and everything decoded here still goes through the same edge
refinement and verification as OpenCV's detections.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.patterns import blurred_patterns, clipped_patterns
from artcal_ros.core.detect.sampling import (
    border_is_dark,
    cell_means,
    module_grid,
    ring_median,
    ring_points,
)
from artcal_ros.core.homography import module_homographies

__all__ = ["PatternTable", "blurred_patterns", "decode_quads", "pattern_correlations"]


class PatternTable:
    """The board's printed patterns in all four corner orders, for fast matching.

    Args:
        board: the calibration board.
        any_polarity: also match the inverted pattern of every marker
            (``board.polarity == "any"``).
        clipped: also match the patterns as an over-exposed sensor sees them
            (:func:`~artcal_ros.core.detect.patterns.clipped_patterns`).
    """

    def __init__(self, board: Board, any_polarity: bool, *, clipped: bool = False) -> None:
        self.ids, self.flat, self.unit, self.levels, self.n = _tables(board, any_polarity,
                                                                      clipped)


@lru_cache(maxsize=16)
def _tables(board: Board, any_polarity: bool, clipped: bool = False
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """A board's pattern tables, made once per board (read-only arrays).

    ``detect(image, board)`` builds a new detector for every image; the tables
    depend on the board only (5 ms a webcam frame when rebuilt each time).
    """
    n = board.bits + 2
    pats = np.stack([board.marker_modules(int(i)) for i in board.ids])  # (N, n, n)
    ids = board.ids
    if any_polarity:
        pats = np.concatenate([pats, ~pats])
        ids = np.concatenate([ids, ids])
    flat = pats.reshape(len(pats), n * n).astype(np.float32)
    # blurred versions, centered and normalised for correlation: (N * L, n * n)
    blurred = blurred_patterns(pats)  # (N, L, n * n)
    if clipped:
        blurred = clipped_patterns(blurred)
    c = blurred - blurred.mean(axis=2, keepdims=True)
    c /= np.maximum(np.linalg.norm(c, axis=2, keepdims=True), 1e-9)
    unit = c.reshape(-1, n * n).astype(np.float32)
    ids = np.array(ids)
    for a in (ids, flat, unit):
        a.flags.writeable = False
    return ids, flat, unit, blurred.shape[1], n


def pattern_correlations(vals: np.ndarray, table: PatternTable, roll: int) -> np.ndarray:
    """(R, N) correlation of R module grids with each of the table's N ids' patterns.

    Args:
        vals: (R, n, n) module means of R quads.
        table: the board's patterns (at a few blur levels; the best level counts).
        roll: the grids are turned by this many quarter turns first.
    """
    R, n = vals.shape[0], vals.shape[1]
    v = np.rot90(vals, k=roll, axes=(1, 2)).reshape(R, n * n)
    v = v - v.mean(axis=1, keepdims=True)
    v = v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-12)
    # einsum, not BLAS: a threaded GEMM of this size spends more time waking its
    # threads than computing (tens of ms on a busy machine instead of ~1 ms)
    return np.asarray(np.einsum("rk,nk->rn", v.astype(np.float32), table.unit
                                ).reshape(R, len(table.ids), table.levels).max(axis=2))


def decode_quads(lin: np.ndarray, quads: np.ndarray, table: PatternTable, *,
                 max_errors: int = 2, grow_px: float = 0.7, ambiguity: float = 0.2,
                 min_corr: float = 0.85, corr_margin: float = 0.12
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Decode candidate quads against the board's patterns.

    Args:
        lin: (H, W) linear intensity image.
        quads: (R, 4, 2) candidate corners, pixels, any order.
        table: the board's patterns.
        max_errors: most modules (of (bits + 2)^2) that may clearly disagree.
        ambiguity: cells closer than this share of the contrast to the threshold
            count neither as agreeing nor as disagreeing (at most 40 % may).
        min_corr, corr_margin: a quad the threshold cannot read is still accepted
            when its module means correlate with one pattern (at some blur level)
            at least this well, and this much better than with any other id.
        grow_px: growth applied to each side first (outward for a dark border,
            inward for a light one), pixels.

    Returns:
        quads (D, 4, 2) re-ordered to the board's TL, TR, BR, BL (grown), ids (D,),
        the index (D,) of each in the input, and every input's module errors (R,).
    """
    if len(quads) == 0:
        return (np.zeros((0, 4, 2)), np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.intp),
                np.zeros(0))
    # a copy: the corner order is changed in place below
    q = np.array(quads, dtype=np.float64).reshape(-1, 4, 2)
    # clockwise in the image (y down), like a marker seen from the front
    x, y = q[..., 0], q[..., 1]
    area = 0.5 * (x * np.roll(y, -1, 1) - np.roll(x, -1, 1) * y).sum(axis=1)
    q[area < 0] = q[area < 0][:, ::-1]
    center = q.mean(axis=1, keepdims=True)
    radius = np.linalg.norm(q - center, axis=2, keepdims=True)
    # the quad finder's contour runs through the dark pixels along the border: inside
    # a dark border, outside a light one
    lin_q = np.asarray(lin)
    dark = border_is_dark(lin_q, q, table.n - 2)
    grow = np.where(dark, grow_px, -grow_px)[:, None, None]
    q = center + (q - center) * (1.0 + grow * np.sqrt(2.0) / np.maximum(radius, 1.0))
    n = table.n
    size = float(n)
    R = len(q)
    best_err: np.ndarray = np.full(R, 10**6)
    best_id: np.ndarray = np.zeros(R, dtype=np.int64)
    best_roll: np.ndarray = np.zeros(R, dtype=np.intp)
    H0 = module_homographies(q, n - 2)
    vals = cell_means(lin, H0, module_grid(n, 0.22)).reshape(R, n, n)
    # the quiet zone just outside the border, half a module out
    s = np.linspace(0.5, size - 0.5, 2 * n)
    quiet = ring_median(lin, H0, ring_points(s, -0.5, size + 0.5))
    border = np.concatenate([vals[:, 0, :], vals[:, -1, :], vals[:, 1:-1, 0], vals[:, 1:-1, -1]],
                            axis=1)
    border_level = np.median(border, axis=1)
    thr = 0.5 * (border_level + quiet)
    # cells within a fifth of the contrast of the threshold (small cells under blur)
    # count neither way
    band = ambiguity * np.abs(quiet - border_level)
    white = vals > (thr + band)[:, None, None]  # (R, n, n)
    black = vals < (thr - band)[:, None, None]
    # blur-aware reading: correlation of the module means with every pattern at a few
    # blur levels (a lone cell under defocus never crosses a threshold, but it still
    # correlates); accepted only with a clear margin over the best other id
    best_corr: np.ndarray = np.full(R, -1.0)
    second_corr: np.ndarray = np.full(R, -1.0)
    corr_id: np.ndarray = np.zeros(R, dtype=np.int64)
    corr_roll: np.ndarray = np.zeros(R, dtype=np.intp)
    for roll in range(4):
        corr = pattern_correlations(vals, table, roll)
        j = np.argmax(corr, axis=1)
        cbest = corr[np.arange(R), j]
        corr[np.arange(R), j] = -1.0
        csecond = corr.max(axis=1)
        better = cbest > best_corr
        second_corr = np.where(better, np.maximum(best_corr, csecond),
                               np.maximum(second_corr, cbest))
        best_corr = np.where(better, cbest, best_corr)
        corr_id = np.where(better, table.ids[j], corr_id)
        corr_roll = np.where(better, roll, corr_roll)
    for roll in range(4):
        # rolling the corners by one turns the sampled pattern by a quarter
        pw = np.rot90(white, k=roll, axes=(1, 2)).reshape(R, n * n).astype(np.float32)
        pb = np.rot90(black, k=roll, axes=(1, 2)).reshape(R, n * n).astype(np.float32)
        # (R, N) confident errors
        dist = np.einsum("rk,nk->rn", pw, 1.0 - table.flat) + np.einsum("rk,nk->rn", pb,
                                                                         table.flat)
        j = np.argmin(dist, axis=1)
        d = dist[np.arange(R), j]
        better = d < best_err
        best_err = np.where(better, d, best_err)
        best_id = np.where(better, table.ids[j], best_id)
        best_roll = np.where(better, roll, best_roll)
    sure = (white | black).reshape(R, -1).mean(axis=1)
    ok = (best_err <= max_errors) & (sure >= 0.6)
    by_corr = ~ok & (best_corr >= min_corr) & (best_corr - second_corr >= corr_margin)
    best_id = np.where(by_corr, corr_id, best_id)
    best_roll = np.where(by_corr, corr_roll, best_roll)
    ok |= by_corr
    out = np.stack([np.roll(q[i], -int(best_roll[i]), axis=0) for i in np.flatnonzero(ok)]) \
        if ok.any() else np.zeros((0, 4, 2))
    return out, best_id[ok], np.flatnonzero(ok), best_err
