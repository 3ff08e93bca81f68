"""Reading the pixels across marker sides (compiled kernels): coarse edge offsets, model samples.

Two reads serve the edge refinement (:mod:`artcal_ros.core.detect.edges`):

* :func:`coarse_offsets`: bilinear profiles across each side and the offset of
  the strongest gradient of the expected sign on each (a first line per side);
* :func:`gather_samples`: the raw pixels of a band across each side that the
  blurred-step model is fitted to (:mod:`artcal_ros.core.detect.step_model`);
* :func:`sample_geometry`: where those samples lie on the marker's module grid, and the
  module width the model places the code behind the border with.

Both loop over sides and profiles in compiled code, which never builds the (S, K, J)
arrays of every candidate point that array code would mask most of again. A point on
side k is ``a + t u + s n`` as in :mod:`.sides`.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
from numba import njit

from artcal_ros.core.detect.lens import Lens
from artcal_ros.core.detect.sampling import bilinear_at
from artcal_ros.core.detect.sides import module_geometry_at
from artcal_ros.core.detect.workers import run_all, split_even
from artcal_ros.core.homography import apply_one, module_homographies

__all__ = ["coarse_offsets", "gather_samples", "sample_geometry"]


@njit(cache=True, error_model="numpy", nogil=True)
def _coarse_kernel(lin: np.ndarray, a: np.ndarray, u: np.ndarray, n: np.ndarray,
                   t: np.ndarray, offsets: np.ndarray, sign: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """See :func:`coarse_offsets`."""
    S, K = t.shape
    J = len(offsets)
    out = np.zeros((S, K))
    valid = np.zeros((S, K), dtype=np.bool_)
    step = offsets[1] - offsets[0]
    for s in range(S):
        prof = np.empty(J)
        g = np.empty(J)
        for k in range(K):
            bx = a[s, 0] + t[s, k] * u[s, 0]
            by = a[s, 1] + t[s, k] * u[s, 1]
            for j in range(J):
                prof[j] = bilinear_at(lin, bx + offsets[j] * n[s, 0], by + offsets[j] * n[s, 1])
            # 1-pixel central difference of the expected sign, -inf outside [lo, hi]
            best = 0
            for j in range(J):
                gj = 0.0
                if 0 < j < J - 1:
                    gj = (prof[j + 1] - prof[j - 1]) * sign[s]
                if not (lo[s] <= offsets[j] <= hi[s]):
                    gj = -np.inf
                g[j] = gj
                if gj > g[best]:
                    best = j
            j0 = min(max(best, 1), J - 2)
            gm, g0, gp = g[j0 - 1], g[j0], g[j0 + 1]
            denom = gm - 2.0 * g0 + gp
            delta = 0.0
            if np.isfinite(denom) and denom < 0:
                delta = 0.5 * (gm - gp) / denom
                if not np.isfinite(delta):
                    delta = 0.0
            delta = min(max(delta, -0.5), 0.5)
            out[s, k] = offsets[j0] + delta * step
            valid[s, k] = np.isfinite(g0) and g0 > 0
    return out, valid


def coarse_offsets(lin: np.ndarray, a: np.ndarray, u: np.ndarray, n: np.ndarray,
                   t: np.ndarray, offsets: np.ndarray, sign: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offset of the strongest gradient of the expected sign inside [lo, hi], per profile.

    Each profile is read by bilinear interpolation at ``a + t u + offsets_j n``;
    the gradient is the 1-pixel central difference, its peak refined by a parabola.

    Args:
        lin: (H, W) float32 linear intensity image.
        a, u, n: (S, 2) side frames.
        t: (S, K) along-side positions of the profiles, pixels.
        offsets: (J,) equally spaced sample offsets along the normal, pixels.
        sign: (S,) +1 where intensity rises outward (dark border), -1 where it falls.
        lo, hi: (S,) search window along the normal, pixels.

    Returns:
        (S, K) offsets, pixels, and a validity mask (S, K) (a rising gradient was found).
    """
    f64 = np.float64
    return _coarse_kernel(lin, np.ascontiguousarray(a, f64), np.ascontiguousarray(u, f64),
                          np.ascontiguousarray(n, f64), np.ascontiguousarray(t, f64),
                          np.ascontiguousarray(offsets, f64), np.ascontiguousarray(sign, f64),
                          np.ascontiguousarray(lo, f64), np.ascontiguousarray(hi, f64))


@njit(cache=True, error_model="numpy", nogil=True)
def _side_samples(s: int, lin: np.ndarray, a: np.ndarray, u: np.ndarray, n: np.ndarray,
                  t: np.ndarray, present: np.ndarray, coef: np.ndarray, length: np.ndarray,
                  curved: np.ndarray, first: int, last: int, inner: np.ndarray,
                  outer: np.ndarray, p0: np.ndarray, nin: np.ndarray, clear: float,
                  out: np.ndarray, basis: np.ndarray, m0: int, write: bool) -> tuple[int, int]:
    """Side s's samples, written from m0 on when ``write``; returns (samples, profiles used)."""
    h, w = lin.shape
    c0, c1, c2 = coef[s, 0], coef[s, 1], coef[s, 2] if curved[s] else 0.0
    L = length[s]
    lo_j = max(first, -math.ceil(inner[s]) - 1)
    hi_j = min(last, math.ceil(outer[s]) + 1)
    m = m0
    used = 0
    for k in range(t.shape[1]):
        if not present[s, k]:
            continue
        tau = 2.0 * t[s, k] / L - 1.0
        s0 = c0 + c1 * tau + c2 * (tau * tau - 1.0 / 3.0)
        bx = a[s, 0] + t[s, k] * u[s, 0] + s0 * n[s, 0]
        by = a[s, 1] + t[s, k] * u[s, 1] + s0 * n[s, 1]
        before = m
        for j in range(lo_j, hi_j + 1):
            x = bx + j * n[s, 0]
            y = by + j * n[s, 1]
            if not (-0.5 < x < w - 0.5 and -0.5 < y < h - 0.5):
                continue
            # the pixel nearest the grid point: the model sees raw pixel values
            px = min(max(np.rint(x), 0.0), w - 1.0)
            py = min(max(np.rint(y), 0.0), h - 1.0)
            rx = px - a[s, 0]
            ry = py - a[s, 1]
            ts = rx * u[s, 0] + ry * u[s, 1]
            ss = rx * n[s, 0] + ry * n[s, 1]
            tau_s = 2.0 * ts / L - 1.0
            quad = tau_s * tau_s - 1.0 / 3.0 if curved[s] else 0.0
            rel = ss - (c0 + c1 * tau_s + c2 * quad)
            if rel < -inner[s] or rel > outer[s]:
                continue
            if rel < 0.0:
                # inside the border: clear of both neighbouring sides
                ok = True
                for q in range(2):
                    dist = ((px - p0[s, q, 0]) * nin[s, q, 0]
                            + (py - p0[s, q, 1]) * nin[s, q, 1])
                    ok &= dist >= clear
                if not ok:
                    continue
            if write:
                out[0, m] = px
                out[1, m] = py
                out[2, m] = ts
                out[3, m] = ss
                out[4, m] = lin[int(py), int(px)]
                out[5, m] = rel
                basis[m, 0] = 1.0
                basis[m, 1] = tau_s
                basis[m, 2] = quad
            m += 1
        if m > before:
            used += 1
    return m - m0, used


@njit(cache=True, error_model="numpy", nogil=True)
def _gather_kernel(which: np.ndarray, start: np.ndarray, lin: np.ndarray, a: np.ndarray,
                   u: np.ndarray, n: np.ndarray, t: np.ndarray, present: np.ndarray,
                   coef: np.ndarray, length: np.ndarray, curved: np.ndarray, first: int,
                   last: int, inner: np.ndarray, outer: np.ndarray, p0: np.ndarray,
                   nin: np.ndarray, clear: float, count: np.ndarray, used: np.ndarray,
                   out: np.ndarray, basis: np.ndarray, write: bool) -> None:
    """The sides ``which``: their sample counts (and profiles used), or with ``write`` their
    samples from ``start[s]`` on; writes only their rows (threads share the arrays)."""
    for s in which:
        count[s], used[s] = _side_samples(s, lin, a, u, n, t, present, coef, length, curved,
                                          first, last, inner, outer, p0, nin, clear,
                                          out, basis, start[s], write)


def gather_samples(lin: np.ndarray, a: np.ndarray, u: np.ndarray, n: np.ndarray,
                   t: np.ndarray, present: np.ndarray, coef: np.ndarray, length: np.ndarray,
                   curved: np.ndarray, offsets: tuple[int, int], inner: np.ndarray,
                   outer: np.ndarray, neighbours: tuple[np.ndarray, np.ndarray], clear: float
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The pixels the step model is fitted to, flat and grouped by side.

    For every profile (a point ``a + t u + e(t) n`` on the current edge curve) the
    pixels nearest the points 1 px apart along the normal are taken, when they
    lie within ``[-inner, outer]`` of the edge curve; a pixel inside the border
    must also be ``clear`` pixels inside both neighbouring sides (near an acute
    corner a cut straight inward would otherwise leave the marker).

    Args:
        lin: (H, W) float32 linear intensity image.
        a, u, n: (S, 2) side frames.
        t, present: (S, K) profile positions, pixels, and mask.
        coef: (S, 3) edge polynomial (see :class:`~.sides.SideModel`); length (S,) pixels;
            curved (S,) bool: the parabola term is used.
        offsets: the first and last integer offset along the normal, pixels.
        inner, outer: (S,) window inside and outside the edge, pixels.
        neighbours: a point (S, 2, 2) on, and the inward unit normal (S, 2, 2) of, the
            previous and the next side of each side's marker, pixels.
        clear: pixels.

    Returns:
        samples (6, N): x, y (the pixel), t, s (its along-side and normal
        coordinates, pixels), its value and its offset from the edge curve along the
        normal, pixels; basis (N, 3), the edge polynomial's basis
        (1, tau, tau^2 - 1/3, the last 0 where not curved) at each; side (N,) int,
        non-decreasing;
        profiles (S,) int, the profiles with at least one sample.
    """
    f64 = np.float64
    S = len(a)
    args = (lin, np.ascontiguousarray(a, f64), np.ascontiguousarray(u, f64),
            np.ascontiguousarray(n, f64), np.ascontiguousarray(t, f64),
            np.ascontiguousarray(present, bool), np.ascontiguousarray(coef, f64),
            np.ascontiguousarray(length, f64), np.ascontiguousarray(curved, bool),
            int(offsets[0]), int(offsets[1]), np.ascontiguousarray(inner, f64),
            np.ascontiguousarray(outer, f64), np.ascontiguousarray(neighbours[0], f64),
            np.ascontiguousarray(neighbours[1], f64), float(clear))
    count = np.zeros(S, np.intp)
    used = np.zeros(S, np.intp)
    # counted first, then written into arrays of that size (an upper-bound buffer costs
    # more in page faults than the second pass), the sides in runs on the worker threads
    runs = split_even(np.arange(S), np.sum(present, axis=1) * (offsets[1] - offsets[0] + 1))
    start = np.zeros(S + 1, np.intp)
    run_all(lambda r: _gather_kernel(r, start, *args, count, used, np.empty((6, 0)),
                                     np.empty((0, 3)), False), runs)
    start[1:] = np.cumsum(count)
    out = np.empty((6, start[-1]))
    basis = np.empty((start[-1], 3))
    run_all(lambda r: _gather_kernel(r, start, *args, count, used, out, basis, True), runs)
    return out, basis, np.repeat(np.arange(S), count), used


class ProfileLayout(Protocol):
    """Where the profiles of S sides lie (:class:`~artcal_ros.core.detect.edges.SideLayout`):
    positions t (S, K) along each side, pixels, evenly spaced; present (S, K) bool, the
    first ones of each side; n (S, 2) outward unit normals."""

    @property
    def t(self) -> np.ndarray: ...

    @property
    def present(self) -> np.ndarray: ...

    @property
    def n(self) -> np.ndarray: ...


@njit(cache=True, error_model="numpy", nogil=True)
def _sample_kernel(Hinv: np.ndarray, side: np.ndarray, pts: np.ndarray, t_pts: np.ndarray,
                   t: np.ndarray, count: np.ndarray, width: np.ndarray, size: float,
                   along: np.ndarray, out: np.ndarray) -> None:
    """Along-side position (modules, in side direction) of points (N, 2) (undistorted) on
    sides (N,), and the profiles' widths (S, K) interpolated at their positions t_pts (N,)."""
    for i in range(len(pts)):
        s = side[i]
        m, k = s // 4, s % 4
        x, y = apply_one(Hinv[m], pts[i, 0], pts[i, 1])
        a = x if k % 2 == 0 else y
        along[i] = size - a if k >= 2 else a
        c = count[s]
        f = (t_pts[i] - t[s, 0]) / (t[s, 1] - t[s, 0]) if c > 1 else 0.0
        if f <= 0.0:
            out[i] = width[s, 0]
        elif f >= c - 1:
            out[i] = width[s, c - 1]
        else:
            j = int(f)
            r = f - j
            out[i] = (1.0 - r) * width[s, j] + r * width[s, j + 1]


def sample_geometry(corners: np.ndarray, pts: np.ndarray, t_pts: np.ndarray,
                    side: np.ndarray, layout: ProfileLayout, base: np.ndarray,
                    plain_width: np.ndarray, bits: int, lens: Lens | None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Along-side position (modules, 0..bits+2) of samples and module width (pixels) at them.

    The width is the border's, from the edge point one module inward
    (:func:`~artcal_ros.core.detect.sides.module_geometry_at`), taken at each profile's point
    on the edge and interpolated along the side to the samples. The width varies slowly
    along a side and a sample's edge point lies within a pixel of its profile's, while
    through a lens every width costs a root-finding (the lens's inverse).

    Args:
        corners: (M, 4, 2) current quads, pixels.
        pts: (N, 2) the samples' pixels; t_pts (N,) their positions along their sides,
            pixels; side (N,) int, their sides (0 .. 4 M - 1).
        layout: where the profiles lie.
        base: (S, K, 2) each profile's point on the current edge, pixels.
        plain_width: (S, K) the module width at ``base`` without a lens, pixels (used when
            ``lens`` is None).
        bits: code cells per marker side.
        lens: optional lens model (the marker's homography is then taken between
            undistorted pixels).

    Returns:
        along (N,) modules and module width (N,) pixels.
    """
    S, K = layout.t.shape
    n = np.ascontiguousarray(layout.n, np.float64)
    width = plain_width
    if lens is not None:
        width = module_geometry_at(corners, base.reshape(-1, 2), np.repeat(np.arange(S), K),
                                   n, bits, lens)[1].reshape(S, K)
    M = len(corners)
    H = module_homographies(
        corners if lens is None
        else lens.undistort(corners.reshape(-1, 2)).reshape(M, 4, 2), bits)
    Hinv = np.linalg.inv(H)
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    pts_u = pts if lens is None else lens.undistort(pts)
    t_pts = np.ascontiguousarray(t_pts, np.float64)
    t = np.ascontiguousarray(layout.t, np.float64)
    count = np.sum(layout.present, axis=1).astype(np.intp)
    width = np.ascontiguousarray(width, np.float64)
    side = np.ascontiguousarray(side, dtype=np.intp)
    along = np.empty(len(pts))
    out = np.empty(len(pts))

    def part(run: np.ndarray) -> None:
        sl = slice(int(run[0]), int(run[-1]) + 1)
        _sample_kernel(Hinv, side[sl], pts_u[sl], t_pts[sl], t, count, width, bits + 2.0,
                       along[sl], out[sl])

    if len(pts):
        run_all(part, split_even(np.arange(len(pts)), np.ones(len(pts))))
    return along, out
