"""Batched plane homographies for marker quads (shared by edge fitting, decoding and checks)."""

from __future__ import annotations

import numpy as np


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
    # plain broadcasting: einsum is slow on the stride-0 (broadcast) point arrays
    x, y = pts[..., 0], pts[..., 1]
    h = H[:, None, :, :]
    X = h[..., 0, 0] * x + h[..., 0, 1] * y + h[..., 0, 2]
    Y = h[..., 1, 0] * x + h[..., 1, 1] * y + h[..., 1, 2]
    W = h[..., 2, 0] * x + h[..., 2, 1] * y + h[..., 2, 2]
    with np.errstate(all="ignore"):
        return np.stack([X / W, Y / W], axis=-1)


def shortest_sides(quads: np.ndarray) -> np.ndarray:
    """(M,) length of each quad's shortest side, pixels (quads (M, 4, 2))."""
    return np.asarray(np.linalg.norm(quads - np.roll(quads, -1, axis=1), axis=2).min(axis=1))


def module_homographies(corners: np.ndarray, bits: int) -> np.ndarray:
    """(M, 3, 3) maps from module coordinates (0..bits+2, x right, y down) to the image.

    Args:
        corners: (M, 4, 2) marker quads TL, TR, BR, BL, pixels.
        bits: code cells per marker side.
    """
    n = bits + 2.0
    square = np.array([[0.0, 0.0], [n, 0.0], [n, n], [0.0, n]])
    return homographies(np.broadcast_to(square, corners.shape).copy(), corners)
