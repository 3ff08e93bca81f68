"""Checks that keep a wrong id away from the solver.

A marker is kept only when (a) its border has the polarity the board prints
for that id (read by :func:`~artcal_ros.core.detect.sampling.border_is_dark`),
(b) the code re-read on the refined quad agrees with the id's pattern in almost
every cell (:func:`code_errors`), (c) its image neighbours sit where its own
homography puts them on the board (:func:`neighbour_support`), and (d) every
refined side reads as the border's outer edge, in view (:func:`sides_are_edges`).
A false decode in clutter fails (b) or (c); a wrong id inside the board fails
(c); a marker running off the image fails (d).

With a lens (a known camera or the frame's estimate) the checks can be read through it:
the homographies then map the board into straightened pixels, where a strongly distorted
marker and its neighbours are projective again (:func:`checks_pass`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.centers import diagonal_centers
from artcal_ros.core.detect.linalg import nanmedian_rows
from artcal_ros.core.detect.patterns import blurred_patterns
from artcal_ros.core.detect.sampling import bilinear, module_grid
from artcal_ros.core.homography import apply_h, homographies, module_homographies, shortest_sides


def sides_are_edges(lin: np.ndarray, corners: np.ndarray, dark: np.ndarray, bits: int,
                    min_share: float = 0.5, *, clipped: bool = False,
                    lens: Any = None) -> np.ndarray:
    """(M,) bool: every refined side lies on the border's outer edge, in view.

    Half a module inside each side must read as the border and half a module
    outside as the quiet zone, on most of the side (off-image points do not
    count), with at least ``min_share`` of the marker's strongest side contrast.
    A marker that runs off the image fails: the quad finder closes it along
    the image edge and the fit settles on an inner edge of the border there.

    Args:
        lin: (H, W) linear intensity image.
        corners: (M, 4, 2) refined corners TL, TR, BR, BL, pixels.
        dark: (M,) bool, the border is darker than the quiet zone.
        bits: code cells per marker side.
        min_share: least contrast of a side, as a share of the marker's strongest side.
        clipped: the frame is over-exposed: the border is read at a quarter, half and
            three quarters of a module inside, darkest (lightest for a light border) of
            the three, and a side needs only half of ``min_share``. The clipped light eats
            into a dark border from both of its edges, by a different part of a pixel on
            each side, and can leave only a thin dark core away from the module's middle,
            whose contrast then differs from side to side by a factor of two or three.
        lens: read the module positions through this lens (``undistort``/``distort`` in
            pixels); None: a homography in the image.
    """
    M = len(corners)
    if M == 0:
        return np.zeros(0, dtype=bool)
    h, w = lin.shape
    n = bits + 2.0
    H = module_homographies(_straightened(corners, lens), bits)
    s = np.linspace(1.5, n - 1.5, 3 * bits)
    # sides in corner order: top (y = 0), right (x = n), bottom (y = n), left (x = 0)
    fixed = np.array([0.0, n, n, 0.0])
    inward = np.array([1.0, -1.0, -1.0, 1.0])
    horizontal = np.array([True, False, True, False])
    contrast = np.zeros((M, 4))
    seen = np.zeros((M, 4))
    # outside: half a module, but no further than 1.5 px (a marker close to the
    # image edge keeps its quiet zone's first pixels in view)
    module_px = shortest_sides(corners) / n
    out_mod = np.minimum(0.5, 1.5 / np.maximum(module_px, 1e-6))
    depths = (0.25, 0.5, 0.75) if clipped else (0.5,)
    for k in range(4):
        reads = []
        for depth in depths:
            c = np.full_like(s, fixed[k] + depth * inward[k])
            inner = np.c_[s, c] if horizontal[k] else np.c_[c, s]
            pin = _to_image(apply_h(H, np.broadcast_to(inner, (M, *inner.shape))), lens)
            reads.append(bilinear(lin, pin[..., 0], pin[..., 1]))
        border_read = reads[0] if len(reads) == 1 else np.where(
            dark[:, None], np.minimum.reduce(reads), np.maximum.reduce(reads))
        c_out = np.repeat((fixed[k] - out_mod * inward[k])[:, None], len(s), axis=1)
        s_b = np.broadcast_to(s, c_out.shape)
        outer = np.stack([s_b, c_out] if horizontal[k] else [c_out, s_b], axis=-1)
        pout = _to_image(apply_h(H, outer), lens)
        on = ((pout[..., 0] >= 0) & (pout[..., 0] <= w - 1) & (pout[..., 1] >= 0)
              & (pout[..., 1] <= h - 1))
        seen[:, k] = on.mean(axis=1)
        vin = np.median(border_read, axis=1)
        vout = nanmedian_rows(np.where(on, bilinear(lin, pout[..., 0], pout[..., 1]), np.nan))
        contrast[:, k] = np.where(dark, vout - vin, vin - vout)
    clean = np.nan_to_num(contrast, nan=-1.0)
    strongest = clean.max(axis=1, keepdims=True)
    share = 0.5 * min_share if clipped else min_share
    ok = (seen >= 0.8) & (clean >= share * strongest) & (strongest > 0)
    return np.asarray(ok.all(axis=1))


def code_errors(lin: np.ndarray, corners: np.ndarray, dark: np.ndarray, ids: np.ndarray,
                board: Board, lens: Any = None) -> np.ndarray:
    """(M,) int: modules (border and code) whose brightness disagrees with the id's pattern.

    Each module is read as the mean of 3 x 3 samples in its central half and
    compared with the id's pattern as it looks under a few levels of blur
    (:func:`~artcal_ros.core.detect.patterns.blurred_patterns`), scaled to the image by least
    squares: a module more than half the contrast away from its prediction is
    wrong. A quad whose contrast comes out inverted counts as all wrong.

    Args:
        lin: (H, W) linear intensity image.
        corners: (M, 4, 2) refined corners TL, TR, BR, BL, pixels.
        dark: (M,) bool, the border is darker than the quiet zone (unused: the
            fitted contrast's sign carries the polarity).
        ids: (M,) marker ids.
        board: the calibration board.
        lens: read the modules through this lens (see :func:`sides_are_edges`).
    """
    M = len(ids)
    if M == 0:
        return np.zeros(0, dtype=np.intp)
    n = board.bits + 2
    H = module_homographies(_straightened(corners, lens), board.bits)
    grid = module_grid(n, 0.25)
    pts = _to_image(apply_h(H, np.broadcast_to(grid, (M, *grid.shape))), lens)
    vals = bilinear(lin, pts[..., 0], pts[..., 1]).reshape(M, n * n, 9).mean(axis=2)
    printed = np.stack([board.marker_modules(int(i)) for i in ids])
    expected = blurred_patterns(printed)  # (M, L, n*n), 1 = white
    # fit vals ~ alpha + beta * expected per blur level; keep the best level
    ec = expected - expected.mean(axis=2, keepdims=True)
    vc = (vals - vals.mean(axis=1, keepdims=True))[:, None, :]
    with np.errstate(all="ignore"):
        beta = (ec * vc).sum(axis=2) / np.maximum((ec * ec).sum(axis=2), 1e-12)
    resid = vc - beta[..., None] * ec
    level = np.argmin((resid * resid).sum(axis=2), axis=1)
    r = resid[np.arange(M), level]
    b = beta[np.arange(M), level]
    # a cell is wrong when it sits more than half the contrast from its prediction
    wrong = (np.abs(r) > 0.5 * np.abs(b)[:, None]).sum(axis=1)
    errors = np.where(b > 0, wrong, n * n).astype(np.intp)
    return errors


def neighbour_support(corners: np.ndarray, ids: np.ndarray, board: Board,
                      tolerance: float, grow_to: float | None = None, lens: Any = None
                      ) -> np.ndarray:
    """(M,) int: how many image neighbours confirm each marker's position on the board.

    Each marker's homography (board plane -> image, from its own four corners)
    predicts where every marker within about three marker sides in the image
    should be. A neighbour within ``tolerance`` marker sides of its prediction
    supports the marker; one further away contradicts it. Returns the support
    count, 0 for a marker without neighbours, or -1 where contradictions are at
    least as many as confirmations (the marker, or its neighbours, has a wrong id).

    Args:
        corners: (M, 4, 2) refined corners TL, TR, BR, BL, pixels.
        ids: (M,) marker ids.
        board: the calibration board.
        tolerance: largest prediction error of a supporting neighbour, marker sides.
        grow_to: where markers are small against their spacing (ChArUco), a marker's own
            homography extrapolates poorly to its neighbours (its corner errors grow with
            the square of the distance): the tolerance then grows as
            ``(board distance / (4/3 marker sides))^2``, up to ``grow_to`` marker sides
            (keep it below half the distance of the nearest other marker position, so a
            wrong id still contradicts).
        lens: compare in this lens's straightened pixels (see :func:`sides_are_edges`).
    """
    M = len(ids)
    if M == 0:
        return np.zeros(0, dtype=np.intp)
    corners = _straightened(corners, lens)
    obj = board.object_corners(ids)[:, :, :2]
    H = homographies(obj, corners)
    centers_img = corners.mean(axis=1)
    size = np.sqrt(np.abs(_quad_area(corners)))
    obj_centers = obj.mean(axis=1)
    pred = apply_h(H, np.broadcast_to(obj_centers, (M, M, 2)))  # (i, j): j predicted by i
    # compare with the marker's diagonal center so perspective does not count as an error
    actual = diagonal_centers(corners, np.zeros((M, 4)), None)[0]
    err = np.linalg.norm(pred - actual[None, :, :], axis=2) / size[:, None]
    dist = np.linalg.norm(centers_img[:, None, :] - centers_img[None, :, :], axis=2)
    near = (dist < 3.0 * size[:, None]) & ~np.eye(M, dtype=bool)
    tol = np.full((M, M), tolerance)
    if grow_to is not None:
        sides = (np.linalg.norm(obj_centers[:, None] - obj_centers[None], axis=2)
                 / board.marker_length)
        tol = np.clip(tolerance * (sides / (4.0 / 3.0)) ** 2, tolerance, max(grow_to, tolerance))
    agree = (near & (err < tol)).sum(axis=1)
    disagree = (near & ~(err < tol)).sum(axis=1)
    out = agree.astype(np.intp)
    out[(disagree > 0) & (disagree >= agree)] = -1
    return out


def checks_pass(lin: np.ndarray, corners: np.ndarray, dark: np.ndarray, ids: np.ndarray,
                board: Board, *, max_bit_errors: int, max_bit_errors_isolated: int | None,
                tolerance: float, grow_to: float | None, clipped: bool,
                lens: Any = None) -> np.ndarray:
    """(M,) bool: code, neighbours and sides check out (module docstring (b)-(d)).

    A marker with neighbours may miss ``max_bit_errors`` code cells, an isolated one
    ``max_bit_errors_isolated`` (None: isolated markers fail); ``tolerance``, ``grow_to``
    as in :func:`neighbour_support`, ``clipped`` and ``lens`` as in :func:`sides_are_edges`.
    """
    errors = code_errors(lin, corners, dark, ids, board, lens)
    support = neighbour_support(corners, ids, board, tolerance, grow_to, lens)
    ok = (errors <= max_bit_errors) & (support > 0)
    if max_bit_errors_isolated is not None:
        ok |= (support == 0) & (errors <= max_bit_errors_isolated)
    ok &= support >= 0
    ok &= sides_are_edges(lin, corners, dark, board.bits, clipped=clipped, lens=lens)
    return np.asarray(ok)


def _straightened(corners: np.ndarray, lens: Any) -> np.ndarray:
    """Corners (M, 4, 2) in ``lens``'s straightened pixels (as given without a lens); NaN
    where a division lens folds, so those markers read as nothing."""
    if lens is None or len(corners) == 0:
        return corners
    flat = corners.reshape(-1, 2)
    out = np.asarray(lens.undistort(flat), dtype=np.float64)
    if hasattr(lens, "one_to_one"):
        out = np.where(lens.one_to_one(flat)[:, None], out, np.nan)
    return out.reshape(corners.shape)


def _to_image(pts: np.ndarray, lens: Any) -> np.ndarray:
    """Straightened points (..., 2) back to image pixels (as given without a lens)."""
    if lens is None:
        return pts
    flat = np.asarray(pts, dtype=np.float64).reshape(-1, 2)
    ok = np.isfinite(flat).all(axis=1)
    out = np.full_like(flat, np.nan)
    out[ok] = lens.distort(flat[ok])
    return out.reshape(pts.shape)


def _quad_area(q: np.ndarray) -> np.ndarray:
    """(...) signed area of quads (..., 4, 2) by the shoelace formula, pixels^2."""
    x, y = q[..., 0], q[..., 1]
    return 0.5 * (x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y).sum(axis=-1)
