"""Batched plane homographies for marker quads (shared by edge fitting, decoding and checks),
and the local affine check of a grid's points against their neighbours."""

from __future__ import annotations

import numpy as np
from numba import njit


def homographies(src: np.ndarray, dst: np.ndarray) -> np.ndarray:
    """(M, 3, 3) homographies mapping src (M, 4, 2) onto dst (M, 4, 2) (batched DLT, h33 = 1)."""
    M = len(src)
    A = np.zeros((M, 8, 8))
    b = np.zeros((M, 8))
    x, y = src[..., 0], src[..., 1]
    u, v = dst[..., 0], dst[..., 1]
    A[:, 0::2, 0] = x
    A[:, 0::2, 1] = y
    A[:, 0::2, 2] = 1.0
    A[:, 0::2, 6] = -x * u
    A[:, 0::2, 7] = -y * u
    A[:, 1::2, 3] = x
    A[:, 1::2, 4] = y
    A[:, 1::2, 5] = 1.0
    A[:, 1::2, 6] = -x * v
    A[:, 1::2, 7] = -y * v
    b[:, 0::2] = u
    b[:, 1::2] = v
    with np.errstate(all="ignore"):
        h = np.linalg.solve(A + 1e-12 * np.eye(8), b[..., None])[..., 0]
    return np.concatenate([h, np.ones((M, 1))], axis=1).reshape(M, 3, 3)


def apply_h(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply (M, 3, 3) homographies to points (M, P, 2) -> (M, P, 2)."""
    # One compiled signature: views (broadcast, sliced, transposed) and read-only arrays
    # are copied to plain writeable ones. Another layout or a read-only flag would be a
    # second signature, compiled on first use inside a running node (holding the GIL).
    H = np.require(H, np.float64, ["C", "W"])
    pts = np.require(pts, np.float64, ["C", "W"])
    return _apply_kernel(H, pts)


@njit(cache=True, error_model="numpy", nogil=True)
def _apply_kernel(H: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Kernel of :func:`apply_h` (non-finite where a point maps to infinity)."""
    M, P = pts.shape[0], pts.shape[1]
    out = np.empty((M, P, 2))
    for m in range(M):
        h = H[m]
        for i in range(P):
            out[m, i, 0], out[m, i, 1] = apply_one(h, pts[m, i, 0], pts[m, i, 1])
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def apply_one(H: np.ndarray, x: float, y: float) -> tuple[float, float]:
    """A homography H (3, 3) applied to one point (x, y); the map of :func:`apply_h`,
    callable from compiled kernels (non-finite where the point maps to infinity)."""
    w = H[2, 0] * x + H[2, 1] * y + H[2, 2]
    return (H[0, 0] * x + H[0, 1] * y + H[0, 2]) / w, (H[1, 0] * x + H[1, 1] * y + H[1, 2]) / w


def shortest_sides(quads: np.ndarray) -> np.ndarray:
    """(M,) length of each quad's shortest side, pixels (quads (M, 4, 2))."""
    return np.asarray(np.linalg.norm(quads - np.roll(quads, -1, axis=1), axis=2).min(axis=1))


def module_homographies(corners: np.ndarray, bits: int) -> np.ndarray:
    """(M, 3, 3) maps from module coordinates (0..bits+2, x right, y down) to the image.

    The square-to-quad map in closed form (Heckbert 1989), h33 = 1; it equals
    :func:`homographies` from the module square, without an 8 x 8 solve per quad.

    Args:
        corners: (M, 4, 2) marker quads TL, TR, BR, BL, pixels.
        bits: code cells per marker side.
    """
    q = np.asarray(corners, dtype=np.float64)
    x0, x1, x2, x3 = (q[:, i, 0] for i in range(4))
    y0, y1, y2, y3 = (q[:, i, 1] for i in range(4))
    dx1, dx2, dx3 = x1 - x2, x3 - x2, x0 - x1 + x2 - x3
    dy1, dy2, dy3 = y1 - y2, y3 - y2, y0 - y1 + y2 - y3
    with np.errstate(all="ignore"):
        den = dx1 * dy2 - dx2 * dy1
        g = (dx3 * dy2 - dx2 * dy3) / den
        h = (dx1 * dy3 - dx3 * dy1) / den
    # the unit square's map, scaled to the module square (0 .. bits + 2)
    s = 1.0 / (bits + 2.0)
    H = np.empty((len(q), 3, 3))
    H[:, 0, 0] = (x1 - x0 + g * x1) * s
    H[:, 0, 1] = (x3 - x0 + h * x3) * s
    H[:, 0, 2] = x0
    H[:, 1, 0] = (y1 - y0 + g * y1) * s
    H[:, 1, 1] = (y3 - y0 + h * y3) * s
    H[:, 1, 2] = y0
    H[:, 2, 0] = g * s
    H[:, 2, 1] = h * s
    H[:, 2, 2] = 1.0
    return H


def neighbour_misfit(points_px: np.ndarray, cells: np.ndarray, radius: int,
                     use: np.ndarray | None = None) -> np.ndarray:
    """(n,) how far each point lies from where its grid neighbours put it, in local pitches.

    Each point is predicted by an affine map of the lattice cells fitted to the points of
    ``use`` within ``radius`` cells of it (itself left out); over a small patch perspective
    and lens are nearly affine, so a point off by a good part of the local pitch (the
    square root of the map's determinant) is misplaced or misidentified.

    Args:
        points_px: (n, 2) image points, pixels.
        cells: (n, 2) their lattice cells (row, column).
        radius: neighbours within this many cells (Chebyshev distance).
        use: (n,) bool, the points that may serve as neighbours (default: all).

    Returns:
        (n,) float; NaN where fewer than 4 neighbours serve or the map is degenerate.
    """
    n = len(points_px)
    rc = np.asarray(cells, dtype=np.float64).reshape(-1, 2)
    near = np.max(np.abs(rc[:, None, :] - rc[None, :, :]), axis=2) <= radius
    np.fill_diagonal(near, False)
    if use is not None:
        near &= np.asarray(use, bool)[None, :]
    # one affine fit per point, all at once: normal equations summed over neighbours
    X = np.column_stack([rc[:, 1], rc[:, 0], np.ones(n)])
    weights = near.astype(np.float64)
    XtX = np.einsum("mj,ja,jb->mab", weights, X, X)
    XtY = np.einsum("mj,ja,jb->mab", weights, X, np.asarray(points_px, dtype=np.float64))
    enough = near.sum(axis=1) >= 4
    XtX[~enough] = np.eye(3)
    coef = np.linalg.solve(XtX + 1e-9 * np.eye(3), XtY)  # (n, 3, 2)
    pitch_px = np.sqrt(np.abs(np.linalg.det(coef[:, :2, :])))
    miss = np.linalg.norm(np.einsum("ma,mab->mb", X, coef) - points_px, axis=1)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = miss / pitch_px
    out[~enough | ~(pitch_px > 0)] = np.nan
    return out
