"""Reading the image: exact bilinear samples, and the border and cell reads every stage uses.

Positions are in OpenCV's pixel convention (the center of the top-left pixel is
(0, 0)); module coordinates run 0 .. bits + 2 across a marker, border included,
x right and y down, mapped to the image by each marker's homography.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from artcal_ros.core.homography import apply_h, module_homographies


def bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample ``image`` (H, W) at float pixel positions (any shape) by bilinear interpolation.

    Exact float arithmetic (``cv2.remap`` quantises positions to 1/32 pixel, which
    is a visible bias at the accuracy aimed for here). Positions outside the image
    are clamped to the border.

    Args:
        image: (H, W) intensities.
        x, y: pixel positions, the same (any) shape.

    Returns:
        the samples, in the shape of ``x``.
    """
    xf = np.ascontiguousarray(x, dtype=np.float64)
    yf = np.ascontiguousarray(y, dtype=np.float64)
    out = _bilinear_kernel(np.ascontiguousarray(image), xf.reshape(-1), yf.reshape(-1))
    return out.reshape(xf.shape)


@njit(cache=True, error_model="numpy", nogil=True)
def _bilinear_kernel(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Kernel of :func:`bilinear` on flat (N,) positions; NaN where a position is not finite."""
    out = np.empty(len(x))
    for i in range(len(x)):
        if not (np.isfinite(x[i]) and np.isfinite(y[i])):
            out[i] = np.nan
            continue
        out[i] = bilinear_at(image, x[i], y[i])
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def bilinear_at(image: np.ndarray, x: float, y: float) -> float:
    """One bilinear sample of ``image`` (H, W) at the finite pixel position (x, y), clamped
    to the image; the sampler of :func:`bilinear`, callable from compiled kernels."""
    h, w = image.shape
    x = min(max(x, 0.0), w - 1.000001)
    y = min(max(y, 0.0), h - 1.000001)
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx = x - x0
    fy = y - y0
    top = image[y0, x0] * (1.0 - fx) + image[y0, x0 + 1] * fx
    bottom = image[y0 + 1, x0] * (1.0 - fx) + image[y0 + 1, x0 + 1] * fx
    return top * (1.0 - fy) + bottom * fy


def ring_points(s: np.ndarray, near: float, far: float) -> np.ndarray:
    """(4 len(s), 2) module points on the four lines y = near, y = far, x = near, x = far.

    Args:
        s: (P,) positions along each line, modules.
        near, far: the two coordinates of the lines, modules.
    """
    a, b = np.full_like(s, near), np.full_like(s, far)
    return np.concatenate([np.c_[s, a], np.c_[s, b], np.c_[a, s], np.c_[b, s]])


def ring_median(lin: np.ndarray, H: np.ndarray, ring: np.ndarray) -> np.ndarray:
    """(M,) median intensity of each marker along a ring of module points.

    Args:
        lin: (H, W) linear intensity image.
        H: (M, 3, 3) module-to-image homographies.
        ring: (P, 2) module points (see :func:`ring_points`).
    """
    pts = apply_h(H, np.broadcast_to(ring, (len(H), *ring.shape)))
    return np.asarray(np.median(bilinear(lin, pts[..., 0], pts[..., 1]), axis=1))


def border_is_dark(lin: np.ndarray, quads: np.ndarray, bits: int) -> np.ndarray:
    """(M,) bool: whether each quad's border band is darker than the ring just outside it.

    Args:
        lin: (H, W) linear intensity image.
        quads: (M, 4, 2) marker corners TL, TR, BR, BL, pixels.
        bits: code cells per marker side.
    """
    if len(quads) == 0:
        return np.zeros(0, dtype=bool)
    n = bits + 2.0
    H = module_homographies(quads, bits)
    s = np.linspace(0.5, n - 0.5, 4 * (bits + 2))
    vin = ring_median(lin, H, ring_points(s, 0.5, n - 0.5))
    vout = ring_median(lin, H, ring_points(s, -0.5, n + 0.5))
    return np.asarray(vin < vout)


def module_grid(n: int, spread: float) -> np.ndarray:
    """(n * n * 9, 2) sample points in module units: 3 x 3 per module, modules row-major.

    Args:
        n: modules per marker side (bits + 2).
        spread: distance of the outer samples from a module's center, modules.
    """
    sub = (np.arange(3) - 1.0) * spread
    cy, cx = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5, indexing="ij")
    px = (cx[..., None, None] + sub[None, None, None, :]).repeat(3, axis=2)
    py = (cy[..., None, None] + sub[None, None, :, None]).repeat(3, axis=3)
    return np.stack([px.ravel(), py.ravel()], axis=1)


def cell_means(lin: np.ndarray, H: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """(M, n * n) mean intensity of every module, modules row-major.

    Args:
        lin: (H, W) linear intensity image.
        H: (M, 3, 3) module-to-image homographies.
        grid: (n * n * 9, 2) module sample points from :func:`module_grid`.
    """
    M = len(H)
    pts = apply_h(H, np.broadcast_to(grid, (M, *grid.shape)))
    vals = bilinear(lin, pts[..., 0], pts[..., 1])
    return np.asarray(vals.reshape(M, len(grid) // 9, 9).mean(axis=2))
