"""Small numerics: a dense solve for the compiled kernels (numba has no LAPACK without
SciPy), and row medians over a mask."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["nanmedian_rows", "solve"]


@njit(cache=True, error_model="numpy")
def solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """x with A x = b for a small square A (n, n) and b (n, k): LU with partial pivoting.

    A singular system gives non-finite entries (the caller treats them as no step).
    """
    n = A.shape[0]
    M = A.copy()
    x = b.copy()
    for c in range(n):
        piv = c
        for r in range(c + 1, n):
            if abs(M[r, c]) > abs(M[piv, c]):
                piv = r
        if piv != c:
            for j in range(n):
                M[c, j], M[piv, j] = M[piv, j], M[c, j]
            for j in range(x.shape[1]):
                x[c, j], x[piv, j] = x[piv, j], x[c, j]
        inv = 1.0 / M[c, c]
        for r in range(c + 1, n):
            f = M[r, c] * inv
            if f != 0.0:
                for j in range(c, n):
                    M[r, j] -= f * M[c, j]
                for j in range(x.shape[1]):
                    x[r, j] -= f * x[c, j]
    for c in range(n - 1, -1, -1):
        for j in range(x.shape[1]):
            acc = x[c, j]
            for k in range(c + 1, n):
                acc -= M[c, k] * x[k, j]
            x[c, j] = acc / M[c, c]
    return x


def nanmedian_rows(x: np.ndarray) -> np.ndarray:
    """(M,) median of each row of x (M, P) over its non-NaN entries; NaN for none.

    As ``np.nanmedian(x, axis=1)`` (the mean of the two middle values for an even
    count), without its masked-array overhead on small rows.
    """
    srt = np.sort(x, axis=1)  # NaN sorts last
    count = (~np.isnan(x)).sum(axis=1)
    lo = np.take_along_axis(srt, np.maximum((count - 1) // 2, 0)[:, None], 1)[:, 0]
    hi = np.take_along_axis(srt, np.maximum(count // 2, 0)[:, None], 1)[:, 0]
    return np.where(count > 0, 0.5 * (lo + hi), np.nan)
