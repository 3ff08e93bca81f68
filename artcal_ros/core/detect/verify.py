"""Checks that keep a wrong id away from the solver, and marker centres.

A marker is kept only when (a) its border has the polarity the board prints
for that id, (b) the code re-read on the refined quad agrees with the id's
pattern in almost every cell, and (c) its image neighbours sit where its own
homography puts them on the board, and (d) every refined side reads as the
border's outer edge, in view. A false decode in clutter fails (b) or (c); a
wrong id inside the board fails (c); a marker running off the image fails (d).
"""

from __future__ import annotations

import warnings

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.edges import bilinear
from artcal_ros.core.detect.lens import DivisionLens, LensModel
from artcal_ros.core.homography import apply_h, homographies, module_homographies, shortest_sides


def _ring(s: np.ndarray, near: float, far: float) -> np.ndarray:
    """Points (4 len(s), 2) on the four lines x or y = near / far, at positions s."""
    a, b = np.full_like(s, near), np.full_like(s, far)
    return np.concatenate([np.c_[s, a], np.c_[s, b], np.c_[a, s], np.c_[b, s]])


def border_is_dark(lin: np.ndarray, quads: np.ndarray, bits: int) -> np.ndarray:
    """(M,) bool: whether each quad's border band is darker than the ring just outside it."""
    if len(quads) == 0:
        return np.zeros(0, dtype=bool)
    n = bits + 2.0
    H = module_homographies(quads, bits)
    s = np.linspace(0.5, n - 0.5, 4 * (bits + 2))
    ring_in = _ring(s, 0.5, n - 0.5)
    ring_out = _ring(s, -0.5, n + 0.5)
    pin = apply_h(H, np.broadcast_to(ring_in, (len(quads), *ring_in.shape)))
    pout = apply_h(H, np.broadcast_to(ring_out, (len(quads), *ring_out.shape)))
    vin = np.median(bilinear(lin, pin[..., 0], pin[..., 1]), axis=1)
    vout = np.median(bilinear(lin, pout[..., 0], pout[..., 1]), axis=1)
    return np.asarray(vin < vout)


def sides_are_edges(lin: np.ndarray, corners: np.ndarray, dark: np.ndarray, bits: int,
                    min_share: float = 0.5) -> np.ndarray:
    """(M,) bool: every refined side lies on the border's outer edge, in view.

    Half a module inside each side must read as the border and half a module
    outside as the quiet zone, on most of the side (off-image points do not
    count), with at least ``min_share`` of the marker's strongest side contrast.
    A marker that runs off the image fails: the quad finder closes it along
    the image edge and the fit settles on an inner edge of the border there.
    """
    M = len(corners)
    if M == 0:
        return np.zeros(0, dtype=bool)
    h, w = lin.shape
    n = bits + 2.0
    H = module_homographies(corners, bits)
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
    for k in range(4):
        c = np.full_like(s, fixed[k] + 0.5 * inward[k])
        inner = np.c_[s, c] if horizontal[k] else np.c_[c, s]
        pin = apply_h(H, np.broadcast_to(inner, (M, *inner.shape)))
        c_out = np.repeat((fixed[k] - out_mod * inward[k])[:, None], len(s), axis=1)
        s_b = np.broadcast_to(s, c_out.shape)
        outer = np.stack([s_b, c_out] if horizontal[k] else [c_out, s_b], axis=-1)
        pout = apply_h(H, outer)
        on = ((pout[..., 0] >= 0) & (pout[..., 0] <= w - 1) & (pout[..., 1] >= 0)
              & (pout[..., 1] <= h - 1))
        seen[:, k] = on.mean(axis=1)
        vin = np.median(bilinear(lin, pin[..., 0], pin[..., 1]), axis=1)
        vout = np.where(on, bilinear(lin, pout[..., 0], pout[..., 1]), np.nan)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # a side wholly off the image
            vout = np.nanmedian(vout, axis=1)
        contrast[:, k] = np.where(dark, vout - vin, vin - vout)
    clean = np.nan_to_num(contrast, nan=-1.0)
    strongest = clean.max(axis=1, keepdims=True)
    ok = (seen >= 0.8) & (clean >= min_share * strongest) & (strongest > 0)
    return np.asarray(ok.all(axis=1))


def inner_border_cells(board: Board, ids: np.ndarray, rows: int = 2) -> np.ndarray:
    """(M, 4, rows, bits) bool: per side, the code cells behind the border that share its colour.

    Row 0 touches the border, row 1 is the next one inward. Sides run TL->TR,
    TR->BR, BR->BL, BL->TL; cells are listed in that direction.
    """
    b = board.bits
    out = np.zeros((len(ids), 4, rows, b), dtype=bool)
    for k, marker_id in enumerate(ids):
        mod = board.marker_modules(int(marker_id))
        same = mod == mod[0, 0]
        for r in range(rows):
            out[k, 0, r] = same[1 + r, 1:b + 1]
            out[k, 1, r] = same[1:b + 1, b - r]
            out[k, 2, r] = same[b - r, 1:b + 1][::-1]
            out[k, 3, r] = same[1:b + 1, 1 + r][::-1]
    return out


def outer_neighbours(board: Board, ids: np.ndarray) -> np.ndarray:
    """(M, 4) bool: per side (top, right, bottom, left), another marker's tile lies beyond it."""
    out = np.zeros((len(ids), 4), dtype=bool)
    for k, marker_id in enumerate(ids):
        row, col = board.cell_of(int(marker_id))
        out[k] = (row > 0, col < board.cols - 1, row < board.rows - 1, col > 0)
    return out


def _blurred(printed: np.ndarray) -> np.ndarray:
    from artcal_ros.core.detect.decode import blurred_patterns

    return blurred_patterns(printed)


def code_errors(lin: np.ndarray, corners: np.ndarray, dark: np.ndarray, ids: np.ndarray,
                board: Board) -> np.ndarray:
    """(M,) int: modules (border and code) whose brightness disagrees with the id's pattern.

    Each module is read as the mean of 3 x 3 samples in its central half and
    compared with the id's pattern as it looks under a few levels of blur
    (:func:`detect_decode.blurred_patterns`), scaled to the image by least
    squares: a module more than half the contrast away from its prediction is
    wrong. A quad whose contrast comes out inverted counts as all wrong.
    """
    M = len(ids)
    if M == 0:
        return np.zeros(0, dtype=np.intp)
    n = board.bits + 2
    H = module_homographies(corners, board.bits)
    sub = (np.arange(3) - 1.0) * 0.25
    cx, cy = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)  # cy: row, cx: col
    px = (cx[..., None, None] + sub[None, None, None, :]).repeat(3, axis=2)
    py = (cy[..., None, None] + sub[None, None, :, None]).repeat(3, axis=3)
    grid = np.stack([px.ravel(), py.ravel()], axis=1)  # (n*n*9, 2), module-major
    pts = apply_h(H, np.broadcast_to(grid, (M, *grid.shape)))
    vals = bilinear(lin, pts[..., 0], pts[..., 1]).reshape(M, n * n, 9).mean(axis=2)
    printed = np.stack([board.marker_modules(int(i)) for i in ids])
    expected = _blurred(printed)  # (M, L, n*n), 1 = white
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
                      tolerance: float) -> np.ndarray:
    """(M,) int: how many image neighbours confirm each marker's position on the board.

    Each marker's homography (board plane -> image, from its own four corners)
    predicts where every marker within about three marker sides in the image
    should be. A neighbour within ``tolerance`` marker sides of its prediction
    supports the marker; one further away contradicts it. Returns the support
    count, 0 for a marker without neighbours, or -1 where contradictions are at
    least as many as confirmations (the marker, or its neighbours, has a wrong id).
    """
    M = len(ids)
    if M == 0:
        return np.zeros(0, dtype=np.intp)
    obj = board.object_corners(ids)[:, :, :2]
    H = homographies(obj, corners)
    centres_img = corners.mean(axis=1)
    size = np.sqrt(np.abs(_quad_area(corners)))
    obj_centres = obj.mean(axis=1)
    pred = apply_h(H, np.broadcast_to(obj_centres, (M, M, 2)))  # (i, j): j predicted by i
    # predict from the marker's diagonal centre so perspective does not count as an error
    actual = diagonal_centres(corners, np.zeros((M, 4)), None)[0]
    err = np.linalg.norm(pred - actual[None, :, :], axis=2) / size[:, None]
    dist = np.linalg.norm(centres_img[:, None, :] - centres_img[None, :, :], axis=2)
    near = (dist < 3.0 * size[:, None]) & ~np.eye(M, dtype=bool)
    agree = (near & (err < tolerance)).sum(axis=1)
    disagree = (near & ~(err < tolerance)).sum(axis=1)
    out = agree.astype(np.intp)
    out[(disagree > 0) & (disagree >= agree)] = -1
    return out


def _quad_area(q: np.ndarray) -> np.ndarray:
    x, y = q[..., 0], q[..., 1]
    return 0.5 * (x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y).sum(axis=-1)


def diagonal_centres(corners: np.ndarray, corner_sigma: np.ndarray,
                     lens: LensModel | DivisionLens | None) -> tuple[np.ndarray, np.ndarray]:
    """Marker centres as the intersection of the quad diagonals, and their 1-sigma errors.

    Under a pinhole projection the image of a square's centre is exactly the
    intersection of its image diagonals. With a lens model the corners are
    undistorted first and the intersection is distorted back, so the result is
    the true image of the centre; without one, the error is of second order in
    the distortion's variation across the marker (a few thousandths of a pixel
    for markers below ~100 px in ordinary lenses).

    Args:
        corners: (M, 4, 2) pixels, TL, TR, BR, BL.
        corner_sigma: (M, 4) 1-sigma corner errors, pixels.
        lens: optional lens model.

    Returns:
        centres (M, 2) pixels and sigmas (M,) pixels (the sigma of the mean of
        four independent corners, exact for a parallelogram).
    """
    M = len(corners)
    if M == 0:
        return np.zeros((0, 2)), np.zeros(0)
    q = corners if lens is None else lens.undistort(corners.reshape(-1, 2)).reshape(M, 4, 2)
    h = np.concatenate([q, np.ones((M, 4, 1))], axis=2)
    d1 = np.cross(h[:, 0], h[:, 2])
    d2 = np.cross(h[:, 1], h[:, 3])
    c = np.cross(d1, d2)
    with np.errstate(all="ignore"):
        centres = c[:, :2] / c[:, 2:3]
    bad = ~np.isfinite(centres).all(axis=1)
    centres[bad] = q[bad].mean(axis=1)
    if lens is not None:
        centres = lens.distort(centres)
    sigma = 0.5 * np.sqrt(np.mean(np.asarray(corner_sigma, dtype=np.float64) ** 2, axis=1))
    return centres, sigma
