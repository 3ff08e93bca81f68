"""Small numerics: a dense solve and a sort for the compiled kernels, and row medians.

The kernels use these rather than numba's ``np.linalg`` (it needs SciPy's LAPACK) and
``np.sort`` / ``np.median`` (their generic implementations took most of the ~45 s of
CPU the kernels needed to compile the first time).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["median_small", "nanmedian_rows", "solve", "sort_small"]


@njit(cache=True, error_model="numpy", nogil=True)
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


@njit(cache=True, error_model="numpy", nogil=True)
def sort_small(x: np.ndarray, n: int) -> None:
    """Sort the first n entries of a short 1-D array in place, ascending (Shell sort)."""
    gap = 1
    while gap < n // 3:
        gap = 3 * gap + 1
    while gap > 0:
        for i in range(gap, n):
            v = x[i]
            j = i
            while j >= gap and x[j - gap] > v:
                x[j] = x[j - gap]
                j -= gap
            x[j] = v
        gap //= 3


@njit(cache=True, error_model="numpy", nogil=True)
def _select(x: np.ndarray, n: int, k: int) -> float:
    """The k-th smallest of the first n entries of x (no NaN), which are reordered so that
    none before index k is larger and none after it smaller (Hoare's selection)."""
    lo, hi = 0, n - 1
    while lo < hi:
        mid = (lo + hi) // 2
        # the median of three as the pivot
        if x[mid] < x[lo]:
            x[mid], x[lo] = x[lo], x[mid]
        if x[hi] < x[lo]:
            x[hi], x[lo] = x[lo], x[hi]
        if x[hi] < x[mid]:
            x[hi], x[mid] = x[mid], x[hi]
        pivot = x[mid]
        i, j = lo, hi
        while i <= j:
            while x[i] < pivot:
                i += 1
            while x[j] > pivot:
                j -= 1
            if i <= j:
                x[i], x[j] = x[j], x[i]
                i += 1
                j -= 1
        # x[lo..j] <= pivot <= x[i..hi], and what lies between equals the pivot
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    return float(x[k])


@njit(cache=True, error_model="numpy", nogil=True)
def median_small(x: np.ndarray, n: int) -> float:
    """Median of the first n (> 0) entries of a 1-D array without NaN, the mean of the two
    middle values for an even n (as sorting would give); reorders those entries.

    A selection, not a sort: linear in n where :func:`sort_small` is not.
    """
    k = (n - 1) // 2
    a = _select(x, n, k)
    b = a
    if n % 2 == 0:
        b = x[k + 1]
        for i in range(k + 2, n):
            b = min(b, x[i])
    return 0.5 * (a + b)


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
