"""The geometry of marker sides: side frames, the fitted edge curve of a side, corners.

All arrays are batched over the S = 4 M sides of M markers; side k of a marker
runs from its corner k to corner k+1 (TL->TR, TR->BR, BR->BL, BL->TL), so
corner k is the intersection of sides k-1 and k. A point on side k is
``a + t u + s n``: ``t`` pixels along the side from its start ``a`` (unit
direction ``u``), ``s`` pixels along its outward unit normal ``n``.
"""

from __future__ import annotations

import numpy as np

from artcal_ros.core.detect.lens import Lens
from artcal_ros.core.homography import module_homographies


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


def normal_equations(A: np.ndarray, w: np.ndarray, s: np.ndarray,
                     pad: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations of a weighted least-squares fit of s ~ A coef, one per side.

    Args:
        A: (S, K, 3) design matrices (see :func:`tau_basis`).
        w: (S, K) weights (0 for unused points).
        s: (S, K) observations (finite everywhere).
        pad: optional (S, 3, 3) added to the normal matrix (keeps unused terms regular).

    Returns:
        N (S, 3, 3) and rhs (S, 3, 1); a tiny ridge keeps N regular for empty sides.
    """
    AtW = (A * w[..., None]).transpose(0, 2, 1)
    N = np.matmul(AtW, A)
    if pad is not None:
        N = N + pad
    N = N + 1e-9 * np.eye(3)
    return N, np.matmul(AtW, s[..., None])


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
        A = self.basis(t)
        w = valid.astype(np.float64)
        s = np.where(valid, s, 0.0)
        eye = np.eye(3)
        # an unused parabola term gets an identity row so the batched solve stays regular
        pad = np.where(self.order >= 3, 0.0, 1.0)[:, None, None] * eye[2][None, :, None] \
            * eye[2][None, None, :]
        for _ in range(iterations):
            N, rhs = normal_equations(A, w, s, pad)
            coef = np.linalg.solve(N, rhs)[..., 0]
            res = s - np.matmul(A, coef[..., None])[..., 0]
            scale = np.maximum(1.4826 * _masked_median(np.abs(res), w > 0), min_sigma_px)
            w = (valid & (np.abs(res) <= reject_sigmas * scale[:, None])).astype(np.float64)
        count = w.sum(axis=1)
        dof = np.maximum(count - self.order, 1.0)
        var = (w * res * res).sum(axis=1) / dof
        N, _ = normal_equations(A, w, s, pad)
        self.coef = coef
        self.cov = np.linalg.inv(N) * var[:, None, None]
        self.cov[:, 2, 2] *= (self.order >= 3)
        self.count = count.astype(np.intp)


def _masked_median(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-row median of x (S, K) over mask (S, K); 0 for empty rows."""
    srt = np.sort(np.where(mask, x, np.inf), axis=1)
    count = mask.sum(axis=1)
    mid = np.take_along_axis(srt, np.maximum(count // 2, 0)[:, None], 1)[:, 0]
    return np.where(count > 0, mid, 0.0)


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
    prev = (np.arange(4 * M).reshape(M, 4) - 1) % 4 + (np.arange(M) * 4)[:, None]
    prev = prev.ravel()
    cur = np.arange(4 * M)
    t_prev = model.length[prev].copy()
    t_cur = np.zeros(4 * M)
    for _ in range(4):
        p1, d1 = _point_tangent(model, a, u, n, prev, t_prev)
        p2, d2 = _point_tangent(model, a, u, n, cur, t_cur)
        # p1 + x d1 = p2 + y d2
        det = d1[:, 0] * (-d2[:, 1]) - d1[:, 1] * (-d2[:, 0])
        rx = p2 - p1
        with np.errstate(all="ignore"):
            x = (rx[:, 0] * (-d2[:, 1]) - rx[:, 1] * (-d2[:, 0])) / det
            y = (d1[:, 0] * rx[:, 1] - d1[:, 1] * rx[:, 0]) / det
        corner = p1 + x[:, None] * d1
        t_prev = t_prev + x * np.einsum("ij,ij->i", d1, u[prev])
        t_cur = t_cur + y * np.einsum("ij,ij->i", d2, u[cur])
    # error: each side's normal offset variance at the corner, mapped through the
    # 2x2 system n_prev . x = d_prev, n_cur . x = d_cur
    v_prev = _offset_var(model, prev, t_prev)
    v_cur = _offset_var(model, cur, t_cur)
    Nmat = np.stack([n[prev], n[cur]], axis=1)  # (S, 2, 2)
    with np.errstate(all="ignore"):
        Ninv = np.linalg.inv(Nmat + 1e-12 * np.eye(2))
    cov = np.einsum("sij,sj,skj->sik", Ninv, np.stack([v_prev, v_cur], axis=1), Ninv)
    sigma = np.sqrt(np.maximum(0.5 * (cov[:, 0, 0] + cov[:, 1, 1]), 0.0))
    return corner.reshape(M, 4, 2), sigma.reshape(M, 4)


def _point_tangent(model: SideModel, a: np.ndarray, u: np.ndarray, n: np.ndarray,
                   sides: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point (N, 2) on the fitted edge of each side (N,) at t (N,), and the unit tangent there."""
    L = model.length[sides]
    quad = model.order[sides] >= 3
    x = tau_basis(t, L, quad)
    tau = x[:, 1]
    c = model.coef[sides]
    s = c[:, 0] + c[:, 1] * tau + np.where(quad, c[:, 2] * x[:, 2], 0.0)
    ds_dt = (c[:, 1] + np.where(quad, 2.0 * c[:, 2] * tau, 0.0)) * 2.0 / L
    p = a[sides] + t[:, None] * u[sides] + s[:, None] * n[sides]
    d = u[sides] + ds_dt[:, None] * n[sides]
    d /= np.hypot(d[:, 0], d[:, 1])[:, None]
    return p, d


def _offset_var(model: SideModel, sides: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(N,) variance of the fitted normal offset of each side (N,) at t (N,), pixels^2."""
    x = tau_basis(t, model.length[sides], model.order[sides] >= 3)
    return np.einsum("sp,spq,sq->s", x, model.cov[sides], x)


def module_geometry_at(corners: np.ndarray, pts: np.ndarray, side: np.ndarray,
                       n: np.ndarray, bits: int,
                       lens: Lens | None = None
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Along-side position (in modules, 0..bits+2) and local module width (pixels).

    With a lens the marker's homography is taken between undistorted pixels, so
    the code cells land where the lens puts them (near the corners of a strongly
    distorted image, the distorted quad's homography misplaces them by up to a
    pixel along the side).

    Args:
        corners: (M, 4, 2) current quads, pixels.
        pts: (N, 2) image points, each belonging to side ``side`` (N,) of a marker.
        side: (N,) int, side index (0 .. 4 M - 1) of each point.
        n: (S, 2) outward normals.
        bits: code cells per marker side.
        lens: optional lens model.

    Returns:
        along (N,) modules and module width (N,) pixels (at least half a pixel).
    """
    size = bits + 2.0
    marker = side // 4
    inward = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])
    k = side % 4
    if lens is None:
        H = module_homographies(corners, bits)
        mod = apply_each(np.linalg.inv(H), marker, pts)
        inner = apply_each(H, marker, mod + inward[k])
    else:
        M = len(corners)
        H = module_homographies(lens.undistort(corners.reshape(-1, 2)).reshape(M, 4, 2), bits)
        mod = apply_each(np.linalg.inv(H), marker, lens.undistort(pts))
        inner = lens.distort(apply_each(H, marker, mod + inward[k]))
    m_px = np.einsum("nd,nd->n", pts - inner, n[side])
    along = np.where(k % 2 == 0, mod[:, 0], mod[:, 1])
    along = np.where(k >= 2, size - along, along)  # in side direction
    return along, np.clip(m_px, 0.5, None)


def apply_each(H: np.ndarray, which: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply homography ``H[which[i]]`` ((M, 3, 3), which (N,)) to each point (N, 2)."""
    h = [np.take(col, which) for col in np.ascontiguousarray(H.reshape(-1, 9).T)]
    x, y = pts[:, 0], pts[:, 1]
    w = h[6] * x + h[7] * y + h[8]
    with np.errstate(all="ignore"):
        return np.stack([(h[0] * x + h[1] * y + h[2]) / w, (h[3] * x + h[4] * y + h[5]) / w],
                        axis=1)
