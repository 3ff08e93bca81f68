"""The geometry of marker sides: side frames, the fitted edge curve of a side, corners, and
the code cells along a side.

All arrays are batched over the S = 4 M sides of M markers; side k of a marker
runs from its corner k to corner k+1 (TL->TR, TR->BR, BR->BL, BL->TL), so
corner k is the intersection of sides k-1 and k. A point on side k is
``a + t u + s n``: ``t`` pixels along the side from its start ``a`` (unit
direction ``u``), ``s`` pixels along its outward unit normal ``n``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from artcal_ros.core.detect.lens import Lens
from artcal_ros.core.detect.linalg import select_small, solve
from artcal_ros.core.detect.step_model import norm_cdf_pdf
from artcal_ros.core.detect.workers import run_all, split_even
from artcal_ros.core.homography import apply_one, module_homographies


def side_frames(quads: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Start point, unit direction, outward unit normal and length of every side.

    Args:
        quads: (M, 4, 2) corners, pixels.

    Returns:
        a (S, 2), u (S, 2), n (S, 2), length (S,) with S = 4 M.
    """
    a = quads.reshape(-1, 2)
    b = np.roll(quads, -1, axis=1).reshape(-1, 2)
    d = b - a
    length = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    u = d / length[:, None]
    n = np.stack([u[:, 1], -u[:, 0]], axis=1)
    center = np.repeat(quads.mean(axis=1), 4, axis=0)
    mid = 0.5 * (a + b)
    flip = np.einsum("ij,ij->i", mid - center, n) < 0
    n[flip] *= -1.0
    return a, u, n, length


def neighbour_lines(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A point (S, 2, 2) on, and the inward normal (S, 2, 2) of, each side's two neighbours.

    Index 0 is the previous side, 1 the next one, of the marker's quad (M, 4, 2).
    """
    start, _, outward, _ = side_frames(corners)
    M = len(corners)
    start, inward = start.reshape(M, 4, 2), -outward.reshape(M, 4, 2)
    p0 = np.stack([np.roll(start, -shift, axis=1).reshape(4 * M, 2) for shift in (-1, 1)], 1)
    nin = np.stack([np.roll(inward, -shift, axis=1).reshape(4 * M, 2) for shift in (-1, 1)], 1)
    return p0, nin


def tau_basis(t: np.ndarray, length: np.ndarray, curved: np.ndarray) -> np.ndarray:
    """(..., 3) basis (1, tau, tau^2 - 1/3) of the edge polynomial, ``tau = 2 t / L - 1``.

    The basis is orthogonal on tau in [-1, 1], so the line terms barely move
    when the parabola term is freed or held.

    Args:
        t: along-side positions, pixels (any shape).
        length: side lengths L, pixels (broadcast with t).
        curved: bool (broadcast with t): the parabola term is used; 0 where not.
    """
    tau = 2.0 * t / length - 1.0
    quad = np.where(curved, tau * tau - 1.0 / 3.0, 0.0)
    return np.stack([np.ones_like(tau), tau, quad], axis=-1)


class SideModel:
    """Edge offset along each side's normal as a polynomial of the along-side position.

    ``s(t) = c0 + c1 tau + c2 (tau^2 - 1/3)`` with ``tau = 2 t / L - 1`` in [-1, 1].

    Args:
        length: (S,) side lengths, pixels.
        order: (S,) 2 (line) or 3 (parabola) per side.

    Attributes:
        coef: (S, 3) polynomial coefficients, pixels.
        cov: (S, 3, 3) their covariance, pixels^2.
        count: (S,) edge points the last fit used.
    """

    def __init__(self, length: np.ndarray, order: np.ndarray) -> None:
        self.length = length
        self.order = order
        self.coef: np.ndarray = np.zeros((len(length), 3))
        self.cov: np.ndarray = np.zeros((len(length), 3, 3))
        self.count: np.ndarray = np.zeros(len(length), dtype=np.intp)

    def basis(self, t: np.ndarray) -> np.ndarray:
        """(S, K, 3) design matrix at along-side positions t (S, K), pixels."""
        return tau_basis(t, self.length[:, None], self.order[:, None] >= 3)

    def basis_at(self, t: np.ndarray, side: np.ndarray) -> np.ndarray:
        """(N, 3) design matrix at along-side positions t (N,) of the given sides (N,)."""
        return tau_basis(t, self.length[side], self.order[side] >= 3)

    def offset(self, t: np.ndarray) -> np.ndarray:
        """(S, K) edge offsets at t (S, K), pixels."""
        return np.matmul(self.basis(t), self.coef[..., None])[..., 0]

    def fit(self, t: np.ndarray, s: np.ndarray, valid: np.ndarray,
            min_sigma_px: float, reject_sigmas: float, iterations: int = 3) -> None:
        """Robust weighted least squares of edge offsets s (S, K) at t (S, K).

        Points further than ``reject_sigmas`` robust sigmas from the fit are dropped
        (re-evaluated each iteration); sides with fewer than 4 points keep no fit.

        Args:
            t, s: (S, K) along-side positions and normal offsets of edge points, pixels.
            valid: (S, K) bool, the points to use.
            min_sigma_px: floor of the robust sigma, pixels (exact points reject nothing).
            reject_sigmas: rejection threshold, in robust sigmas.
            iterations: reweighting rounds.
        """
        f64 = np.float64
        self.coef, self.cov, self.count = _robust_fit(
            np.ascontiguousarray(t, f64), np.ascontiguousarray(s, f64),
            np.ascontiguousarray(valid, bool), np.ascontiguousarray(self.length, f64),
            np.ascontiguousarray(self.order >= 3), float(min_sigma_px), float(reject_sigmas),
            int(iterations))


@njit(cache=True, error_model="numpy")
def _robust_fit(t: np.ndarray, s: np.ndarray, valid: np.ndarray, length: np.ndarray,
                curved: np.ndarray, min_sigma: float, reject: float, iterations: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Kernel of :meth:`SideModel.fit`: coef (S, 3), cov (S, 3, 3), count (S,)."""
    S, K = t.shape
    coef = np.zeros((S, 3))
    cov = np.zeros((S, 3, 3))
    count = np.zeros(S, np.intp)
    A = np.empty((K, 3))
    obs = np.empty(K)
    res = np.empty(K)
    w = np.empty(K)
    buf = np.empty(K)
    N = np.empty((3, 3))
    rhs = np.empty((3, 1))
    for k in range(S):
        for j in range(K):
            tau = 2.0 * t[k, j] / length[k] - 1.0
            A[j, 0] = 1.0
            A[j, 1] = tau
            A[j, 2] = tau * tau - 1.0 / 3.0 if curved[k] else 0.0
            w[j] = 1.0 if valid[k, j] else 0.0
            obs[j] = s[k, j] if valid[k, j] else 0.0
        c0 = c1 = c2 = 0.0
        for _ in range(iterations):
            _weighted_normal(A, w, obs, curved[k], N, rhs)
            sol = solve(N, rhs)
            c0, c1, c2 = sol[0, 0], sol[1, 0], sol[2, 0]
            m = 0
            for j in range(K):
                res[j] = obs[j] - (A[j, 0] * c0 + A[j, 1] * c1 + A[j, 2] * c2)
                if w[j] > 0:
                    buf[m] = abs(res[j])
                    m += 1
            # robust sigma from the median absolute residual (the upper middle value)
            med = select_small(buf, m, m // 2)[0] if m > 0 else 0.0
            scale = max(1.4826 * med, min_sigma)
            for j in range(K):
                w[j] = 1.0 if (valid[k, j] and abs(res[j]) <= reject * scale) else 0.0
        n_used = 0.0
        sq = 0.0
        for j in range(K):
            n_used += w[j]
            sq += w[j] * res[j] * res[j]
        var = sq / max(n_used - (3.0 if curved[k] else 2.0), 1.0)
        _weighted_normal(A, w, obs, curved[k], N, rhs)
        unit = np.zeros((3, 3))
        for p in range(3):
            unit[p, p] = 1.0
        inv = solve(N, unit)
        coef[k, 0], coef[k, 1], coef[k, 2] = c0, c1, c2
        for p in range(3):
            for q in range(3):
                cov[k, p, q] = inv[p, q] * var
        if not curved[k]:
            cov[k, 2, 2] = 0.0
        count[k] = int(n_used)
    return coef, cov, count


@njit(cache=True, error_model="numpy", nogil=True)
def _weighted_normal(A: np.ndarray, w: np.ndarray, obs: np.ndarray, curved: bool,
                     N: np.ndarray, rhs: np.ndarray) -> None:
    """N (3, 3) = A^T W A (+ an identity row for an unused parabola term, + a tiny ridge),
    rhs (3, 1) = A^T W obs, for one side's rows A (K, 3), weights w (K,), observations (K,)."""
    N[:] = 0.0
    rhs[:] = 0.0
    for j in range(len(w)):
        if w[j] == 0.0:
            continue
        for p in range(3):
            rhs[p, 0] += A[j, p] * w[j] * obs[j]
            for q in range(3):
                N[p, q] += A[j, p] * w[j] * A[j, q]
    if not curved:
        N[2, 2] += 1.0
    for p in range(3):
        N[p, p] += 1e-9


def intersect_sides(model: SideModel, a: np.ndarray, u: np.ndarray, n: np.ndarray,
                    M: int) -> tuple[np.ndarray, np.ndarray]:
    """Corners as intersections of consecutive side curves, with 1-sigma errors.

    Corner k lies at the end (t = L) of side k-1 and the start (t = 0) of side k.
    For parabolas the intersection is found by a few tangent-line iterations.

    Args:
        model: the fitted sides (S = 4 M).
        a, u, n: (S, 2) side frames (:func:`side_frames`).
        M: markers.

    Returns:
        corners (M, 4, 2) pixels and their 1-sigma errors per axis (M, 4), pixels.
    """
    f64 = np.float64
    corner, sigma = _intersect_kernel(
        np.ascontiguousarray(model.coef, f64), np.ascontiguousarray(model.cov, f64),
        np.ascontiguousarray(model.length, f64), np.ascontiguousarray(model.order >= 3),
        np.ascontiguousarray(a, f64), np.ascontiguousarray(u, f64),
        np.ascontiguousarray(n, f64))
    return corner.reshape(M, 4, 2), sigma.reshape(M, 4)


@njit(cache=True, error_model="numpy", nogil=True)
def _point_tangent(coef: np.ndarray, length: np.ndarray, curved: np.ndarray, a: np.ndarray,
                   u: np.ndarray, n: np.ndarray, k: int, t: float
                   ) -> tuple[float, float, float, float]:
    """Point (x, y) on the fitted edge of side k at t, and the unit tangent (dx, dy) there."""
    L = length[k]
    tau = 2.0 * t / L - 1.0
    c2 = coef[k, 2] if curved[k] else 0.0
    s = coef[k, 0] + coef[k, 1] * tau + c2 * (tau * tau - 1.0 / 3.0)
    ds_dt = (coef[k, 1] + 2.0 * c2 * tau) * 2.0 / L
    dx = u[k, 0] + ds_dt * n[k, 0]
    dy = u[k, 1] + ds_dt * n[k, 1]
    norm = math.hypot(dx, dy)
    return (a[k, 0] + t * u[k, 0] + s * n[k, 0], a[k, 1] + t * u[k, 1] + s * n[k, 1],
            dx / norm, dy / norm)


@njit(cache=True, error_model="numpy", nogil=True)
def _offset_var(cov: np.ndarray, length: np.ndarray, curved: np.ndarray, k: int,
                t: float) -> float:
    """Variance of side k's fitted normal offset at t, pixels^2."""
    tau = 2.0 * t / length[k] - 1.0
    x = (1.0, tau, tau * tau - 1.0 / 3.0 if curved[k] else 0.0)
    v = 0.0
    for i in range(3):
        for j in range(3):
            v += x[i] * cov[k, i, j] * x[j]
    return v


@njit(cache=True, error_model="numpy")
def _intersect_kernel(coef: np.ndarray, cov: np.ndarray, length: np.ndarray,
                      curved: np.ndarray, a: np.ndarray, u: np.ndarray, n: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Corners (S, 2) and their sigmas (S,): see :func:`intersect_sides`."""
    S = len(length)
    corner = np.empty((S, 2))
    sigma = np.empty(S)
    for cur in range(S):
        prev = cur - cur % 4 + (cur % 4 + 3) % 4
        t_prev, t_cur = length[prev], 0.0
        for _ in range(4):
            x1, y1, dx1, dy1 = _point_tangent(coef, length, curved, a, u, n, prev, t_prev)
            x2, y2, dx2, dy2 = _point_tangent(coef, length, curved, a, u, n, cur, t_cur)
            # p1 + x d1 = p2 + y d2
            det = dx1 * (-dy2) - dy1 * (-dx2)
            rx, ry = x2 - x1, y2 - y1
            xs = (rx * (-dy2) - ry * (-dx2)) / det
            ys = (dx1 * ry - dy1 * rx) / det
            corner[cur, 0] = x1 + xs * dx1
            corner[cur, 1] = y1 + xs * dy1
            t_prev += xs * (dx1 * u[prev, 0] + dy1 * u[prev, 1])
            t_cur += ys * (dx2 * u[cur, 0] + dy2 * u[cur, 1])
        # error: each side's normal offset variance at the corner, mapped through the
        # 2x2 system n_prev . x = d_prev, n_cur . x = d_cur
        v = (_offset_var(cov, length, curved, prev, t_prev),
             _offset_var(cov, length, curved, cur, t_cur))
        m00, m01 = n[prev, 0] + 1e-12, n[prev, 1]
        m10, m11 = n[cur, 0], n[cur, 1] + 1e-12
        det = m00 * m11 - m01 * m10
        inv = ((m11 / det, -m01 / det), (-m10 / det, m00 / det))
        c00 = inv[0][0] ** 2 * v[0] + inv[0][1] ** 2 * v[1]
        c11 = inv[1][0] ** 2 * v[0] + inv[1][1] ** 2 * v[1]
        half = 0.5 * (c00 + c11)
        sigma[cur] = 0.0 if half < 0.0 else math.sqrt(half)  # NaN stays NaN
    return corner, sigma


def module_geometry_at(corners: np.ndarray, pts: np.ndarray, side: np.ndarray,
                       n: np.ndarray, bits: int,
                       lens: Lens | None = None, offset: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Along-side position (in modules, 0..bits+2) and module width (pixels) at points.

    With a lens the marker's homography is taken between undistorted pixels, so
    the code cells land where the lens puts them (near the corners of a strongly
    distorted image, the distorted quad's homography misplaces them by up to a
    pixel along the side).

    The width is the border's: from the edge point of the point's profile (the point
    moved ``offset`` back along the normal) one module inward, so it says where the
    code behind the border begins even where the image scale changes across the side
    (a fisheye's outer field); taken at the point itself it would misplace the code.

    Args:
        corners: (M, 4, 2) current quads, pixels.
        pts: (N, 2) image points, each belonging to side ``side`` (N,) of a marker.
        side: (N,) int, side index (0 .. 4 M - 1) of each point.
        n: (S, 2) outward normals.
        bits: code cells per marker side.
        lens: optional lens model.
        offset: optional (N,) each point's offset from its side's edge along ``n``,
            pixels (none: the points are on the edge).

    Returns:
        along (N,) modules at the points and module width (N,) pixels (at least half a
        pixel) at their edge points.
    """
    pts = np.ascontiguousarray(pts, dtype=np.float64)
    side = np.ascontiguousarray(side, dtype=np.intp)
    n = np.ascontiguousarray(n, np.float64)
    edge = pts if offset is None else _edge_points(
        pts, side, n, np.ascontiguousarray(offset, np.float64))
    M = len(corners)
    H = module_homographies(
        corners if lens is None
        else lens.undistort(corners.reshape(-1, 2)).reshape(M, 4, 2), bits)
    Hinv = np.linalg.inv(H)
    along = np.empty(len(pts))
    width = np.empty(len(pts))

    def part(run: np.ndarray) -> None:
        # points in consecutive runs on the worker threads (every step is per point)
        sl = slice(int(run[0]), int(run[-1]) + 1)
        p, e = pts[sl], edge[sl]
        if lens is None:
            p_u, e_u = p, e
        elif offset is None:
            p_u = e_u = lens.undistort(p)
        else:
            p_u, e_u = lens.undistort(p), lens.undistort(e)
        mod, inner = _module_points(Hinv, H, side[sl], p_u, e_u)
        if lens is not None:
            inner = lens.distort(inner)
        along[sl], width[sl] = _along_width(mod, inner, e, side[sl], n, bits + 2.0)

    if len(pts):
        run_all(part, split_even(np.arange(len(pts)), np.ones(len(pts))))
    return along, width


@njit(cache=True, error_model="numpy", nogil=True)
def _edge_points(pts: np.ndarray, side: np.ndarray, n: np.ndarray, offset: np.ndarray
                 ) -> np.ndarray:
    """(N, 2) points (N, 2) moved back by their offsets (N,) along their sides' normals."""
    out = np.empty_like(pts)
    for i in range(len(pts)):
        out[i, 0] = pts[i, 0] - offset[i] * n[side[i], 0]
        out[i, 1] = pts[i, 1] - offset[i] * n[side[i], 1]
    return out


@njit(cache=True, error_model="numpy", nogil=True)
def _module_points(Hinv: np.ndarray, H: np.ndarray, side: np.ndarray, pts: np.ndarray,
                   edge: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Module coordinates (N, 2) of points (N, 2) on sides (N,), and the image of the point
    one module further inward from each point's edge point ``edge`` (N, 2) (both through
    the marker's homography)."""
    mod = np.empty_like(pts)
    inner = np.empty_like(pts)
    for i in range(len(pts)):
        m, k = side[i] // 4, side[i] % 4
        x, y = apply_one(Hinv[m], pts[i, 0], pts[i, 1])
        mod[i, 0], mod[i, 1] = x, y
        x, y = apply_one(Hinv[m], edge[i, 0], edge[i, 1])
        # one module inward: +y from the top side, -x from the right, -y, +x
        if k == 0:
            y += 1.0
        elif k == 1:
            x -= 1.0
        elif k == 2:
            y -= 1.0
        else:
            x += 1.0
        inner[i, 0], inner[i, 1] = apply_one(H[m], x, y)
    return mod, inner


@njit(cache=True, error_model="numpy", nogil=True)
def _along_width(mod: np.ndarray, inner: np.ndarray, pts: np.ndarray, side: np.ndarray,
                 n: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Position along each side, modules (in side direction), and module width, pixels,
    from module coordinates (N, 2), the inner points (N, 2) and the points (N, 2) the
    widths are measured from."""
    along = np.empty(len(pts))
    width = np.empty(len(pts))
    for i in range(len(pts)):
        k = side[i] % 4
        a = mod[i, 0] if k % 2 == 0 else mod[i, 1]
        along[i] = size - a if k >= 2 else a
        w = (pts[i, 0] - inner[i, 0]) * n[side[i], 0] + (pts[i, 1] - inner[i, 1]) * n[side[i], 1]
        width[i] = max(w, 0.5)  # NaN stays NaN, as np.clip does
        if np.isnan(w):
            width[i] = w
    return along, width


@njit(cache=True, error_model="numpy", nogil=True)
def _far_cells(along: np.ndarray, side: np.ndarray, same: np.ndarray, blur_modules: np.ndarray,
               out: np.ndarray) -> None:
    """Kernel of :func:`far_cells`, into out (N, R) for the points given (a run of them)."""
    bits = same.shape[2]
    for i in range(len(along)):
        k = side[i]
        w = max(blur_modules[k], 1e-3)
        for r in range(same.shape[1]):
            # sum over cells j of other_j (Phi(x - (j+1)) - Phi(x - (j+2))), regrouped by
            # boundary: only the boundaries where the colour changes need a CDF
            acc = 0.0
            before = 0.0  # the border itself: its own colour
            for j in range(bits + 1):
                other = 0.0 if j == bits or same[k, r, j] else 1.0
                if other != before:
                    acc += (other - before) * norm_cdf_pdf((along[i] - (j + 1)) / w)[0]
                    before = other
            out[i, r] = acc


def far_cells(along: np.ndarray, side: np.ndarray, same: np.ndarray,
              blur_modules: np.ndarray) -> np.ndarray:
    """(N, R) share of the other colour in each of R code rows behind the border, blurred along it.

    Gaussian blur is separable, so behind a straight border the code cells'
    contribution at along-side position x is the sum over cells of the other
    colour of ``Phi((x - x0) / w) - Phi((x - x1) / w)`` (the ``c`` of the
    module docstring's model).

    Args:
        along: (N,) position of each sample along its side, modules (0 .. bits + 2).
        side: (N,) int, each sample's side.
        same: (S, R, bits) bool, per side and code row: the cells (in side order) that
            share the border's colour.
        blur_modules: (S,) blur of each side, in modules along the side.
    """
    along = np.ascontiguousarray(along, np.float64)
    side = np.ascontiguousarray(side, np.intp)
    same = np.ascontiguousarray(same, bool)
    blur = np.ascontiguousarray(blur_modules, np.float64)
    out = np.empty((len(along), same.shape[1]))

    def part(run: np.ndarray) -> None:
        sl = slice(int(run[0]), int(run[-1]) + 1)
        _far_cells(along[sl], side[sl], same, blur, out[sl])

    if len(along):
        run_all(part, split_even(np.arange(len(along)), np.ones(len(along))))
    return out
