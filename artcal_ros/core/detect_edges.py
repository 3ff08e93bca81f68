"""Sub-pixel marker corners from fitted border edges (the ARTag way).

Each side of a marker's outer border is a step edge between the border and the
quiet zone around the marker. For every side we cut many short intensity
profiles across the edge (skipping the ends near the corners), locate the edge
in each profile to a fraction of a pixel, fit a line (or, for a long side bent
by lens distortion, a parabola) robustly through those edge points, and
intersect neighbouring sides to get the corners.

Why the profiles are read in *linear* intensity: a pixel integrates light,
and the gamma encoding comes afterwards. A blurred step is symmetric about the
edge in linear light, not in gamma-encoded grey values, so a grey-level
midpoint of the encoded image sits toward the dark side. The caller passes an
already linearised image.

Edge location in a profile (the "symmetric area" estimator): with the profile
centred on the current edge estimate, take the levels ``lo``/``hi`` at equal
distances ``-r``/``+r`` and integrate the normalised profile
``q = (I - lo) / (hi - lo)`` over ``[-r, r]``. For any symmetric blur the area
is exactly ``r`` when the edge is at 0, and ``r - area`` is the edge offset
otherwise (exact for a sharp step); two re-centred passes converge. It needs no
asymptotic black/white levels, which a thin border band never reaches under
blur, and it integrates the noise over the whole window.

All arrays are batched over the S = 4 M sides of M markers; side k of a marker
runs from its corner k to corner k+1 (TL->TR, TR->BR, BR->BL, BL->TL), so
corner k is the intersection of sides k-1 and k.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from artcal_ros.core.detect_lens import LensModel

_STEP = 0.25  # profile sample spacing, pixels


@dataclass(frozen=True)
class EdgeFit:
    """Result of refining M quads.

    Attributes:
        corners_px: (M, 4, 2) float64, pixels, refined corners in the input order.
        corner_sigma_px: (M, 4) float64, 1-sigma error of each corner per axis, pixels.
        side_rms_px: (M, 4) float64, RMS residual of each side's edge points about its fit.
        contrast: (M, 4) float64, median |hi - lo| of each side's profiles (linear units).
        ok: (M,) bool, every side had enough edge points for a fit.
    """

    corners_px: np.ndarray
    corner_sigma_px: np.ndarray
    side_rms_px: np.ndarray
    contrast: np.ndarray
    ok: np.ndarray


def bilinear(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample ``image`` (H, W) at float pixel positions (any shape) by bilinear interpolation.

    Exact float arithmetic (``cv2.remap`` quantises positions to 1/32 pixel, which
    is a visible bias at the accuracy aimed for here). Positions outside the image
    are clamped to the border.
    """
    h, w = image.shape
    x = np.clip(x, 0.0, w - 1.000001)
    y = np.clip(y, 0.0, h - 1.000001)
    x0 = np.floor(x).astype(np.intp)
    y0 = np.floor(y).astype(np.intp)
    fx = x - x0
    fy = y - y0
    flat = image.ravel()
    i = y0 * w + x0
    top = flat[i] * (1.0 - fx) + flat[i + 1] * fx
    bottom = flat[i + w] * (1.0 - fx) + flat[i + w + 1] * fx
    return top * (1.0 - fy) + bottom * fy


def _side_frames(quads: np.ndarray) -> tuple[np.ndarray, ...]:
    """Start point, unit direction, outward unit normal and length of every side.

    Args:
        quads: (M, 4, 2) corners.

    Returns:
        a (S, 2), u (S, 2), n (S, 2), length (S,) with S = 4 M.
    """
    a = quads.reshape(-1, 2)
    b = np.roll(quads, -1, axis=1).reshape(-1, 2)
    d = b - a
    length = np.maximum(np.hypot(d[:, 0], d[:, 1]), 1e-9)
    u = d / length[:, None]
    n = np.stack([u[:, 1], -u[:, 0]], axis=1)
    centre = np.repeat(quads.mean(axis=1), 4, axis=0)
    mid = 0.5 * (a + b)
    flip = np.einsum("ij,ij->i", mid - centre, n) < 0
    n[flip] *= -1.0
    return a, u, n, length


class _SideModel:
    """Edge offset along each side's normal as a polynomial of the along-side position.

    ``s(t) = c0 + c1 tau + c2 (tau^2 - 1/3)`` with ``tau = 2 t / L - 1`` in [-1, 1];
    ``order`` (S,) is 2 (line) or 3 (parabola) per side.
    """

    def __init__(self, length: np.ndarray, order: np.ndarray) -> None:
        self.length = length
        self.order = order
        self.coef: np.ndarray = np.zeros((len(length), 3))
        self.cov: np.ndarray = np.zeros((len(length), 3, 3))
        self.rms: np.ndarray = np.full(len(length), np.nan)
        self.count: np.ndarray = np.zeros(len(length), dtype=np.intp)

    def basis(self, t: np.ndarray) -> np.ndarray:
        """(S, K, 3) design matrix at along-side positions t (S, K)."""
        tau = 2.0 * t / self.length[:, None] - 1.0
        quad = np.where(self.order[:, None] >= 3, tau * tau - 1.0 / 3.0, 0.0)
        return np.stack([np.ones_like(tau), tau, quad], axis=-1)

    def offset(self, t: np.ndarray) -> np.ndarray:
        """(S, K) edge offsets at t (S, K)."""
        return np.einsum("skp,sp->sk", self.basis(t), self.coef)

    def fit(self, t: np.ndarray, s: np.ndarray, valid: np.ndarray,
            min_sigma_px: float, reject_sigmas: float, iterations: int = 3) -> None:
        """Robust weighted least squares of edge offsets s (S, K) at t (S, K).

        Points further than ``reject_sigmas`` robust sigmas from the fit are dropped
        (re-evaluated each iteration); sides with fewer than 4 points keep no fit.
        """
        A = self.basis(t)
        w = valid.astype(np.float64)
        s = np.where(valid, s, 0.0)
        eye = np.eye(3)
        # an unused parabola term gets an identity row so the batched solve stays regular
        pad = np.where(self.order >= 3, 0.0, 1.0)[:, None, None] * eye[2][None, :, None] \
            * eye[2][None, None, :]
        for _ in range(iterations):
            AtW = A * w[..., None]
            N = np.einsum("skp,skq->spq", AtW, A) + pad + 1e-9 * eye
            rhs = np.einsum("skp,sk->sp", AtW, s)
            coef = np.linalg.solve(N, rhs[..., None])[..., 0]
            res = s - np.einsum("skp,sp->sk", A, coef)
            absr = np.where(valid, np.abs(res), np.nan)
            with np.errstate(all="ignore"):
                mad = 1.4826 * np.nanmedian(np.where(w > 0, absr, np.nan), axis=1)
            scale = np.maximum(np.nan_to_num(mad, nan=min_sigma_px), min_sigma_px)
            w = (valid & (np.abs(res) <= reject_sigmas * scale[:, None])).astype(np.float64)
        count = w.sum(axis=1)
        dof = np.maximum(count - self.order, 1.0)
        var = (w * res * res).sum(axis=1) / dof
        AtW = A * w[..., None]
        N = np.einsum("skp,skq->spq", AtW, A) + pad + 1e-9 * eye
        self.coef = coef
        self.cov = np.linalg.inv(N) * var[:, None, None]
        self.cov[:, 2, 2] *= (self.order >= 3)
        self.rms = np.sqrt(var)
        self.count = count.astype(np.intp)


def _profiles(lin: np.ndarray, a: np.ndarray, u: np.ndarray, n: np.ndarray,
              t: np.ndarray, s0: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Intensities (S, K, J) at ``a + t u + (s0 + offsets_j) n``."""
    base = a[:, None, :] + t[..., None] * u[:, None, :] + s0[..., None] * n[:, None, :]
    pts = base[:, :, None, :] + offsets[None, None, :, None] * n[:, None, None, :]
    return bilinear(lin, pts[..., 0], pts[..., 1])


def _coarse_offsets(prof: np.ndarray, offsets: np.ndarray, sign: np.ndarray,
                    lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offset of the strongest gradient of the expected sign inside [lo, hi] per side.

    Returns (S, K) offsets and a validity mask.
    """
    g = np.zeros_like(prof)
    g[..., 2:-2] = prof[..., 4:] - prof[..., :-4]  # 1-pixel central difference
    g *= sign[:, None, None]
    inside = (offsets[None, :] >= lo[:, None]) & (offsets[None, :] <= hi[:, None])
    g = np.where(inside[:, None, :], g, -np.inf)
    j = np.clip(np.argmax(g, axis=-1), 1, len(offsets) - 2)
    gm = np.take_along_axis(g, (j - 1)[..., None], -1)[..., 0]
    g0 = np.take_along_axis(g, j[..., None], -1)[..., 0]
    gp = np.take_along_axis(g, (j + 1)[..., None], -1)[..., 0]
    denom = gm - 2.0 * g0 + gp
    with np.errstate(all="ignore"):
        delta = np.where(np.isfinite(denom) & (denom < 0), 0.5 * (gm - gp) / denom, 0.0)
    delta = np.clip(np.nan_to_num(delta), -0.5, 0.5)
    valid = np.isfinite(g0) & (g0 > 0)
    return offsets[j] + delta * _STEP, valid


def _area_offsets(prof: np.ndarray, r_steps: np.ndarray, centre: int,
                  min_contrast: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Symmetric-area edge offsets (see the module docstring) per profile.

    Args:
        prof: (S, K, J) intensities on a grid centred at index ``centre``.
        r_steps: (S,) half window per side, in grid steps.
        centre: index of offset 0.
        min_contrast: profiles with |hi - lo| below this are invalid.

    Returns:
        offsets (S, K) pixels, valid (S, K), contrast (S, K).
    """
    _, K, J = prof.shape
    idx = np.arange(J)
    lo = np.take_along_axis(prof, (centre - r_steps)[:, None, None].repeat(K, 1), -1)[..., 0]
    hi = np.take_along_axis(prof, (centre + r_steps)[:, None, None].repeat(K, 1), -1)[..., 0]
    span = hi - lo
    with np.errstate(all="ignore"):
        q = (prof - lo[..., None]) / span[..., None]
    inside = np.abs(idx[None, :] - centre) <= r_steps[:, None]
    # trapezoid rule on [-r, r]: half weight at the two ends
    wts = inside.astype(np.float64)
    ends = np.abs(idx[None, :] - centre) == r_steps[:, None]
    wts[ends] = 0.5
    area = np.einsum("skj,sj->sk", np.nan_to_num(q), wts) * _STEP
    r = r_steps * _STEP
    off = r[:, None] - area
    valid = np.abs(span) >= min_contrast
    valid &= np.abs(off) <= r[:, None]
    return off, valid, np.abs(span)


def refine_quads(lin: np.ndarray, quads: np.ndarray, dark_inside: np.ndarray, bits: int, *,
                 margin_px: float = 2.5, level_modules: float = 0.4,
                 min_level_px: float = 0.75, max_level_px: float = 2.5,
                 curve_min_px: float = 60.0, allow_curvature: bool = True,
                 min_contrast: float = 0.02, passes: int = 2,
                 lens: LensModel | None = None) -> EdgeFit:
    """Refine approximate quads to sub-pixel corners from their border edges.

    Args:
        lin: (H, W) float64 image in linear intensity (roughly 0..1).
        quads: (M, 4, 2) float64, approximate corners (within ~1.5 px), pixels.
        dark_inside: (M,) bool, True where the marker's border is darker than its
            surroundings (black-on-white).
        bits: code cells per side (the border adds two modules).
        margin_px: profiles closer than this to a corner are skipped (the other
            side's blur reaches there).
        level_modules, min_level_px, max_level_px: half width r of the profile
            window, in modules, clamped to [min, max] pixels.
        curve_min_px: sides at least this long may be fitted with a parabola
            (kept only where its curvature is significant).
        allow_curvature: False fits straight lines only (use it when the image
            has been undistorted or a camera model handles distortion).
        min_contrast: smallest |hi - lo| (linear units) for a usable profile.
        passes: re-centred passes of the fine estimator.
        lens: optional lens model; the final edge points are then mapped to
            undistorted pixels, fitted with straight lines there, and the
            corners mapped back.

    Returns:
        the :class:`EdgeFit`.
    """
    M = len(quads)
    if M == 0:
        z = np.zeros((0, 4))
        return EdgeFit(np.zeros((0, 4, 2)), z, z, z, np.zeros(0, dtype=bool))
    quads = np.asarray(quads, dtype=np.float64)
    lin = np.asarray(lin, dtype=np.float64)
    a, u, n, length = _side_frames(quads)
    S = len(a)
    module = length / (bits + 2)
    sign = np.repeat(np.where(dark_inside, 1.0, -1.0), 4)

    # along-side profile positions, the same count K for every side (padded)
    usable = np.maximum(length - 2.0 * margin_px, 0.0)
    k_side = np.clip(np.round(usable).astype(np.intp), 0, 160)
    K = max(int(k_side.max()), 1)
    kk = np.arange(K)[None, :]
    t = margin_px + (kk + 0.5) / np.maximum(k_side[:, None], 1) * usable[:, None]
    present = kk < k_side[:, None]

    order = np.where(allow_curvature & (length >= curve_min_px), 3, 2)
    model = _SideModel(length, order)

    # coarse pass: strongest gradient near the approximate side (the quad finder's
    # contour runs up to a pixel inside the true edge)
    reach = np.minimum(0.45 * module, 4.0)
    offsets: np.ndarray = np.arange(-4.0 - 1.0, 5.5 + 1.0 + 1e-9, _STEP)
    prof = _profiles(lin, a, u, n, t, np.zeros_like(t), offsets)
    s_edge, valid = _coarse_offsets(prof, offsets, sign, -reach, reach + 1.5)
    valid &= present
    model.fit(t, s_edge, valid, min_sigma_px=0.05, reject_sigmas=3.0)

    r_steps = np.round(np.clip(level_modules * module, min_level_px, max_level_px)
                       / _STEP).astype(np.intp)
    jmax = int(r_steps.max())
    offsets = np.arange(-jmax, jmax + 1) * _STEP
    contrast: np.ndarray = np.zeros((S, K))
    for _ in range(max(passes, 1)):
        s0 = model.offset(t)
        prof = _profiles(lin, a, u, n, t, s0, offsets)
        off, valid, contrast = _area_offsets(prof, r_steps, jmax, min_contrast)
        valid &= present
        model.fit(t, s0 + off, valid, min_sigma_px=0.01, reject_sigmas=3.0)

    # keep a parabola only where its curvature is significant; otherwise refit a line
    curved = order >= 3
    if curved.any():
        c2 = model.coef[:, 2]
        sd = np.sqrt(np.maximum(model.cov[:, 2, 2], 1e-30))
        keep = curved & (np.abs(c2) > 3.0 * sd)
        if (curved & ~keep).any():
            model.order = np.where(keep, 3, 2)
            model.fit(t, s0 + off, valid, min_sigma_px=0.01, reject_sigmas=3.0)

    corners, sigma = _intersect(model, a, u, n, M)
    if lens is not None:
        corners, sigma, model = _straight_in_undistorted(
            lens, a + 0.0, u, n, t, s0 + off, valid, corners, M)
    side_ok = model.count >= 4
    ok = side_ok.reshape(M, 4).all(axis=1) & np.isfinite(corners).all(axis=(1, 2))
    med_contrast = np.nanmedian(np.where(valid, contrast, np.nan), axis=1) \
        if valid.any() else np.zeros(S)
    return EdgeFit(corners, sigma, model.rms.reshape(M, 4),
                   np.nan_to_num(med_contrast).reshape(M, 4), ok)


def _intersect(model: _SideModel, a: np.ndarray, u: np.ndarray, n: np.ndarray,
               M: int) -> tuple[np.ndarray, np.ndarray]:
    """Corners as intersections of consecutive side curves, with 1-sigma errors.

    Corner k lies at the end (t = L) of side k-1 and the start (t = 0) of side k.
    For parabolas the intersection is found by a few tangent-line iterations.
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


def _point_tangent(model: _SideModel, a: np.ndarray, u: np.ndarray, n: np.ndarray,
                   sides: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point on the fitted edge of each side at t, and the unit tangent there."""
    L = model.length[sides]
    tau = 2.0 * t / L - 1.0
    c = model.coef[sides]
    quad = model.order[sides] >= 3
    s = c[:, 0] + c[:, 1] * tau + np.where(quad, c[:, 2] * (tau * tau - 1.0 / 3.0), 0.0)
    ds_dt = (c[:, 1] + np.where(quad, 2.0 * c[:, 2] * tau, 0.0)) * 2.0 / L
    p = a[sides] + t[:, None] * u[sides] + s[:, None] * n[sides]
    d = u[sides] + ds_dt[:, None] * n[sides]
    d /= np.hypot(d[:, 0], d[:, 1])[:, None]
    return p, d


def _offset_var(model: _SideModel, sides: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Variance of the fitted normal offset of each side at t."""
    L = model.length[sides]
    tau = 2.0 * t / L - 1.0
    quad = model.order[sides] >= 3
    x = np.stack([np.ones_like(tau), tau, np.where(quad, tau * tau - 1.0 / 3.0, 0.0)], axis=1)
    return np.einsum("sp,spq,sq->s", x, model.cov[sides], x)


def _straight_in_undistorted(lens: LensModel, a: np.ndarray, u: np.ndarray, n: np.ndarray,
                             t: np.ndarray, s: np.ndarray, valid: np.ndarray,
                             corners: np.ndarray, M: int
                             ) -> tuple[np.ndarray, np.ndarray, _SideModel]:
    """Refit the edge points as straight lines in undistorted pixels; corners mapped back."""
    pts = a[:, None, :] + t[..., None] * u[:, None, :] + s[..., None] * n[:, None, :]
    und = lens.undistort(pts.reshape(-1, 2)).reshape(pts.shape)
    und_quads = lens.undistort(corners.reshape(-1, 2)).reshape(M, 4, 2)
    a2, u2, n2, length2 = _side_frames(und_quads)
    rel = und - a2[:, None, :]
    t2 = np.einsum("skd,sd->sk", rel, u2)
    s2 = np.einsum("skd,sd->sk", rel, n2)
    model = _SideModel(length2, np.full(len(a2), 2))
    model.fit(t2, s2, valid, min_sigma_px=0.01, reject_sigmas=3.0)
    und_corners, sigma = _intersect(model, a2, u2, n2, M)
    out = lens.distort(und_corners.reshape(-1, 2)).reshape(M, 4, 2)
    return out, sigma, model
