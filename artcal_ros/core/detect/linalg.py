"""Small numerics: a dense solve and a selection for the compiled kernels, and row medians.

The kernels use these rather than numba's ``np.linalg`` (it needs SciPy's LAPACK) and
``np.sort`` / ``np.median`` (their generic implementations took most of the ~45 s of
CPU the kernels needed to compile the first time).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["median_small", "nanmedian_rows", "select_small", "solve"]


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
def select_small(x: np.ndarray, n: int, k: int) -> tuple[float, float]:
    """The k-th and (k+1)-th smallest (inf for k = n - 1) of the first n entries of a 1-D
    array without NaN (k from 0), which are left as they are.

    Each round moves the values below and above a pivot (the median of three) to the two
    ends of the other buffer, with no branch on the values (a branch would guess wrong on
    half of them), and goes on in the part that holds rank k: linear in n on average.
    """
    src, dst, spare = x, np.empty(n), np.empty(n)
    s0, m = 0, n          # the candidates are src[s0:s0 + m], rank k among them
    above = np.inf        # the smallest value above every candidate
    while m > 1:
        p0, p1, p2 = src[s0], src[s0 + m // 2], src[s0 + m - 1]
        if p0 > p1:
            p0, p1 = p1, p0
        if p1 > p2:
            p1 = p2
        pivot = max(p0, p1)
        lo, hi = 0, m - 1
        for i in range(s0, s0 + m):
            v = src[i]
            dst[lo] = v
            dst[hi] = v
            lo += v < pivot
            hi -= v > pivot
        # dst[:lo] < pivot, dst[hi + 1:m] > pivot, and lo <= k <= hi ranks the pivot itself
        if k < lo:
            above = pivot
            s0, m = 0, lo
        elif k > hi:
            k -= hi + 1
            s0, m = hi + 1, m - 1 - hi
        else:
            nxt = pivot if k < hi else above
            for i in range(hi + 1, m):
                nxt = min(nxt, dst[i])
            return pivot, nxt
        src, dst, spare = dst, spare, dst
    return src[s0], above


@njit(cache=True, error_model="numpy", nogil=True)
def median_small(x: np.ndarray, n: int) -> float:
    """Median of the first n (> 0) entries of a 1-D array without NaN, the mean of the two
    middle values for an even n (as sorting would give).

    A selection (:func:`select_small`), not a sort: linear in n on average.
    """
    a, b = select_small(x, n, (n - 1) // 2)
    return 0.5 * (a + (b if n % 2 == 0 else a))


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
