"""Sub-pixel marker corners from fitted border edges (the ARTag way).

Each side of a marker's outer border is a step edge between the border and the
quiet zone around the marker. For every side we take many short cuts across
the edge (skipping the ends near the corners), locate the edge to a fraction of
a pixel, fit a line (or a curve, where lens distortion bends the side) through
it robustly, and intersect neighbouring sides to get the corners.

Why the image is read in *linear* intensity: a pixel integrates light, and the
gamma encoding comes afterwards. A blurred step is symmetric about the edge in
linear light, not in gamma-encoded grey values, so a grey-level midpoint of the
encoded image sits toward the dark side. The caller passes a linearised image.

Two estimators:

- ``model`` (the default, :mod:`artcal_ros.core.detect.step_model`): the raw pixels
  of a band across each side are fitted with a blurred-step model (the pixel's
  square footprint, a Gaussian blur per side, the code cells behind the border
  from the decoded id). Sides are then, with a lens given or estimated from the
  sides' curvature (plumb lines, pooled over frames by :class:`LensPool`), bent
  exactly as the lens bends a straight edge.
- ``area`` (kept for comparison; faster): bilinear profiles across the edge;
  with the profile centred on the current estimate, the levels ``lo``/``hi`` at
  ``-r``/``+r`` and the area of ``q = (I - lo) / (hi - lo)`` over ``[-r, r]``
  give the offset ``r - area`` (exact for any symmetric blur when centred; a
  measured gain corrects wide blur); a robust line fit follows.

All arrays are batched over the S = 4 M sides of M markers; side k of a marker
runs from its corner k to corner k+1 (TL->TR, TR->BR, BR->BL, BL->TL), so
corner k is the intersection of sides k-1 and k.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from artcal_ros.core.detect.lens import DivisionLens, LensModel, LensPool
from artcal_ros.core.detect.step_model import fit_step_model, phi_cdf, side_median, side_slots
from artcal_ros.core.homography import module_homographies, shortest_sides

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
        lens: the lens model the straight lines were fitted under: the one given,
            one estimated from the edges' curvature (:class:`DivisionLens`), or None.
    """

    corners_px: np.ndarray
    corner_sigma_px: np.ndarray
    side_rms_px: np.ndarray
    contrast: np.ndarray
    ok: np.ndarray
    lens: LensModel | DivisionLens | None = None


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

    def basis_at(self, t: np.ndarray, side: np.ndarray) -> np.ndarray:
        """(N, 3) design matrix at along-side positions t (N,) of the given sides (N,)."""
        tau = 2.0 * t / self.length[side] - 1.0
        quad = np.where(self.order[side] >= 3, tau * tau - 1.0 / 3.0, 0.0)
        return np.stack([np.ones_like(tau), tau, quad], axis=-1)

    def offset(self, t: np.ndarray) -> np.ndarray:
        """(S, K) edge offsets at t (S, K)."""
        return np.matmul(self.basis(t), self.coef[..., None])[..., 0]

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
            N = np.matmul(AtW.transpose(0, 2, 1), A) + pad + 1e-9 * eye
            rhs = np.matmul(AtW.transpose(0, 2, 1), s[..., None])
            coef = np.linalg.solve(N, rhs)[..., 0]
            res = s - np.matmul(A, coef[..., None])[..., 0]
            scale = np.maximum(1.4826 * _masked_median(np.abs(res), w > 0), min_sigma_px)
            w = (valid & (np.abs(res) <= reject_sigmas * scale[:, None])).astype(np.float64)
        count = w.sum(axis=1)
        dof = np.maximum(count - self.order, 1.0)
        var = (w * res * res).sum(axis=1) / dof
        AtW = A * w[..., None]
        N = np.matmul(AtW.transpose(0, 2, 1), A) + pad + 1e-9 * eye
        self.coef = coef
        self.cov = np.linalg.inv(N) * var[:, None, None]
        self.cov[:, 2, 2] *= (self.order >= 3)
        self.rms = np.sqrt(var)
        self.count = count.astype(np.intp)


def _masked_median(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Per-row median of x (S, K) over mask (S, K); 0 for empty rows."""
    srt = np.sort(np.where(mask, x, np.inf), axis=1)
    count = mask.sum(axis=1)
    mid = np.take_along_axis(srt, np.maximum(count // 2, 0)[:, None], 1)[:, 0]
    return np.where(count > 0, mid, 0.0)


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
    g[..., 1:-1] = prof[..., 2:] - prof[..., :-2]  # 1-pixel central difference
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
    return offsets[j] + delta * (offsets[1] - offsets[0]), valid


def _area_offsets(prof: np.ndarray, r_steps: np.ndarray, centre: int,
                  min_contrast: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Symmetric-area edge offsets (see the module docstring) per profile.

    When the blur is wide compared with the window the raw estimate shrinks
    toward the window centre by a gain c < 1 (the normalised profile is nearly
    linear inside the window). The gain is measured per side by shifting the
    window one grid step either way, and divided out: one Newton step.

    Args:
        prof: (S, K, J) intensities on a grid centred at index ``centre``; the grid
            must reach one step beyond every side's window.
        r_steps: (S,) half window per side, in grid steps.
        centre: index of offset 0.
        min_contrast: profiles with |hi - lo| below this are invalid.

    Returns:
        offsets (S, K) pixels, valid (S, K), contrast (S, K).
    """
    r = r_steps * _STEP
    raw = []
    for shift in (0, -1, 1):
        off, span = _window_area(prof, r_steps, centre + shift)
        raw.append(off)
    valid = np.abs(span) >= min_contrast
    slope = (raw[1] - raw[2]) / (2.0 * _STEP)
    gain = _masked_median(np.where(np.isfinite(slope), slope, 0.0), valid)
    gain = np.clip(gain, 0.1, 1.5)
    off = raw[0] / gain[:, None]
    valid &= np.isfinite(off) & (np.abs(off) <= r[:, None])
    return np.nan_to_num(off), valid, np.abs(span)


def _window_area(prof: np.ndarray, r_steps: np.ndarray, centre: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Raw ``r - area`` offsets (S, K) of windows [-r, r] about grid index ``centre``.

    Also returns the level difference hi - lo (S, K) of the window at ``centre``.
    """
    _, K, J = prof.shape
    idx = np.arange(J)
    lo = np.take_along_axis(prof, (centre - r_steps)[:, None, None].repeat(K, 1), -1)[..., 0]
    hi = np.take_along_axis(prof, (centre + r_steps)[:, None, None].repeat(K, 1), -1)[..., 0]
    span = hi - lo
    with np.errstate(all="ignore"):
        q = (prof - lo[..., None]) / span[..., None]
    dist = np.abs(idx[None, :] - centre)
    # trapezoid rule on [-r, r]: half weight at the two ends
    wts = (dist <= r_steps[:, None]).astype(np.float64)
    wts[dist == r_steps[:, None]] = 0.5
    area = np.matmul(np.nan_to_num(q), wts[:, :, None])[..., 0] * _STEP
    return r_steps[:, None] * _STEP - area, span


def refine_quads(lin: np.ndarray, quads: np.ndarray, dark_inside: np.ndarray, bits: int, *,
                 margin_px: float = 1.5, level_modules: float = 0.4,
                 min_level_px: float = 0.75, max_level_px: float = 2.5,
                 curve_min_px: float = 60.0, allow_curvature: bool = True,
                 min_contrast: float = 0.02, passes: int = 2,
                 lens: LensModel | DivisionLens | None = None,
                 inner_same: np.ndarray | None = None,
                 quiet_modules: float = 1.0, outer_same: np.ndarray | None = None,
                 beyond_modules: float = 1.0, method: str = "model",
                 max_profiles: int = 40, lens_pool: LensPool | None = None) -> EdgeFit:
    """Refine approximate quads to sub-pixel corners from their border edges.

    Args:
        lin: (H, W) float64 image in linear intensity (roughly 0..1).
        quads: (M, 4, 2) float64, approximate corners (within ~1.5 px), pixels.
        dark_inside: (M,) bool, True where the marker's border is darker than its
            surroundings (black-on-white).
        bits: code cells per side (the border adds two modules).
        margin_px: profiles closer than this to a corner are skipped (the other
            side's blur reaches there).
        level_modules, min_level_px, max_level_px: smallest half width r of the
            profile window, in modules (it widens up to the room before the next
            edge), clamped to [min, max] pixels.
        curve_min_px: sides at least this long may be fitted with a parabola
            (kept only where its curvature is significant).
        allow_curvature: False fits straight lines only (use it when the image
            has been undistorted or a camera model handles distortion).
        min_contrast: smallest |hi - lo| (linear units) for a usable profile.
        passes: re-centred passes of the fine estimator.
        inner_same: optional (M, 4, rows, bits) bool (see
            :func:`detect_verify.inner_border_cells`): per side, the code cells of
            the first rows behind the border (in side order) that have the
            border's colour. The model fit uses them to model the code's edges
            behind the border; without them the window stops short of the code.
        quiet_modules: width of the quiet zone outside the border, in modules.
        outer_same: optional (M, 4) bool, per side: the board has a known edge back
            to the border's colour at the quiet zone's end (the neighbouring tile
            of a mixed board). The model fit then models that edge and reaches up
            to ``beyond_modules`` past it; without it the window stops short of
            the quiet zone's end.
        method: ``model`` (blurred-step model fit, :mod:`detect_model`) or ``area``
            (the symmetric-area estimator of this module's docstring).
        max_profiles: most profiles per side (long sides are sampled sparser).
        lens_pool: evidence about the lens from earlier frames of the same camera
            (used and extended when the lens is estimated here).
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
    lin = np.asarray(lin, dtype=np.float32)
    sign = np.repeat(np.where(dark_inside, 1.0, -1.0), 4)
    # coarse pass: strongest gradient near the approximate side. The quad finder's
    # contour runs through the pixels on the dark side of the border edge: up to a
    # pixel or two inside a black border, outside a white one.
    inward = np.where(sign > 0, 0.0, 1.5)
    _, _, _, length0 = _side_frames(quads)
    reach = np.minimum(0.45 * length0 / (bits + 2), 4.0)
    model, t, present, a, u, n = _coarse_lines(lin, quads, sign, -reach - inward,
                                               reach + 1.5 - inward, margin_px,
                                               max_profiles)
    # the profiles, the windows and the along-side margins are then laid out again
    # from the quad those lines give: the quad finder's corners can be a pixel or two
    # off, which puts the margins (and the model's code cells) in the wrong place
    coarse, _ = _intersect(model, a, u, n, M)
    quads = np.where(same_edges(coarse, quads)[:, None, None], coarse, quads)
    model, t, present, a, u, n = _coarse_lines(lin, quads, sign, np.full(4 * M, -1.0),
                                               np.full(4 * M, 1.0), margin_px, max_profiles)
    length = model.length
    S = len(a)
    module = length / (bits + 2)
    order = np.where(allow_curvature & (length >= curve_min_px), 3, 2)
    model.order = order

    used_lens: LensModel | DivisionLens | None = lens
    if method == "model":
        # lines (parabolas on long sides when curvature is allowed); then, with a lens
        # given or estimated from those parabolas, every side bent as the lens bends a
        # straight edge and only its offset and angle fitted
        # with the lens still to be estimated from this pass's free parabolas, the
        # edge beyond a narrow quiet zone waits for the lens-aware pass below
        later = lens is None and allow_curvature
        contrast = _model_passes(lin, quads, a, u, n, t, present, model, module, bits,
                                 inner_same, quiet_modules, passes, order, None, margin_px,
                                 None if later else outer_same, beyond_modules)
        valid = present
        if later:
            used_lens = _estimate_division(model, quads, t, valid, lin.shape, pool=lens_pool)
        if used_lens is not None:
            model.order = np.full(S, 3)
            model.coef[:, 2] = _lens_bend(used_lens, a, u, n, length)
            contrast = _model_passes(lin, quads, a, u, n, t, present, model, module, bits,
                                     inner_same, quiet_modules, 1, np.full(S, 2),
                                     used_lens, margin_px, outer_same, beyond_modules)
        else:
            _drop_flat_parabolas(model, None)
            if later and outer_same is not None:
                contrast = _model_passes(lin, quads, a, u, n, t, present, model, module,
                                         bits, inner_same, quiet_modules, 1, model.order,
                                         None, margin_px, outer_same, beyond_modules)
        corners, sigma = _intersect(model, a, u, n, M)
    else:
        k_side = present.sum(axis=1)
        contrast, valid = _area_passes(lin, a, u, n, t, present, model, module, k_side,
                                       inner_same, quiet_modules, level_modules,
                                       min_level_px, max_level_px, min_contrast, passes)
        corners, sigma = _intersect(model, a, u, n, M)
        if lens is not None:
            corners, _, _ = _straight_in_undistorted(
                lens, a, u, n, t, model.offset(t), valid, corners, M)
    side_ok = model.count >= 4
    ok = side_ok.reshape(M, 4).all(axis=1) & np.isfinite(corners).all(axis=(1, 2))
    return EdgeFit(corners, sigma, model.rms.reshape(M, 4), contrast.reshape(M, 4), ok,
                   used_lens)


def same_edges(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """(M,) bool: refined quads (M, 4, 2) still on the edges of the quads they came from.

    The quad finder's polygon can be a few pixels off on large, bent markers;
    a corner that moved further than 3 px and a tenth of the shortest side has
    found a different edge (NaN corners fail too).
    """
    moved = np.abs(new - old).max(axis=(1, 2))
    return np.asarray(moved < np.maximum(3.0, 0.1 * shortest_sides(old)))


def _coarse_lines(lin: np.ndarray, quads: np.ndarray, sign: np.ndarray, lo: np.ndarray,
                  hi: np.ndarray, margin_px: float, max_profiles: int
                  ) -> tuple[_SideModel, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                             np.ndarray]:
    """Straight edge lines from the strongest gradient within [lo, hi] of each quad side.

    Also lays out the along-side profile positions: the same count K for every
    side (padded), ``margin_px`` clear of the corners.

    Returns:
        the line model, t (S, K), present (S, K), and the side frames a, u, n.
    """
    a, u, n, length = _side_frames(quads)
    usable = np.maximum(length - 2.0 * margin_px, 0.0)
    k_side = np.clip(np.round(usable).astype(np.intp), 0, max_profiles)
    K = max(int(k_side.max()), 1)
    kk = np.arange(K)[None, :]
    t = margin_px + (kk + 0.5) / np.maximum(k_side[:, None], 1) * usable[:, None]
    present = kk < k_side[:, None]
    model = _SideModel(length, np.full(len(a), 2))
    # every other profile is enough for a first line
    tc, pc = t[:, ::2], present[:, ::2]
    first = min(float(lo.min()), 0.0) - 1.0
    last = max(float(hi.max()), 0.0) + 1.0
    offsets: np.ndarray = np.arange(first, last + 1e-9, 2 * _STEP)
    prof = _profiles(lin, a, u, n, tc, np.zeros_like(tc), offsets)
    s_edge, valid = _coarse_offsets(prof, offsets, sign, lo, hi)
    model.fit(tc, s_edge, valid & pc, min_sigma_px=0.05, reject_sigmas=3.0)
    return model, t, present, a, u, n


def _area_passes(lin: np.ndarray, a: np.ndarray, u: np.ndarray, n: np.ndarray,
                 t: np.ndarray, present: np.ndarray, model: _SideModel, module: np.ndarray,
                 k_side: np.ndarray, inner_same: np.ndarray | None, quiet_modules: float,
                 level_modules: float, min_level_px: float, max_level_px: float,
                 min_contrast: float, passes: int) -> tuple[np.ndarray, np.ndarray]:
    """Symmetric-area passes (module docstring); updates ``model``; returns contrast, valid."""
    S, K = t.shape
    # window half-width: stay a blur allowance clear of the next edge on either side
    allowance = 1.0 + 0.25 * module
    inner_room = module - allowance
    if inner_same is not None:
        same0 = np.asarray(inner_same, bool).reshape(S, -1, model_bits(inner_same))[:, 0]
        clean = _clean_profiles(t, model.length, same0)
        enough = (clean & present).sum(axis=1) >= np.maximum(6, 0.25 * k_side)
        present = np.where(enough[:, None], present & clean, present)
        inner_room = np.where(enough, 2.0 * module - allowance, inner_room)
    outer_room = quiet_modules * module - allowance
    r_px = np.maximum(np.minimum(inner_room, outer_room), level_modules * module)
    r_steps = np.round(np.clip(r_px, min_level_px, max_level_px) / _STEP).astype(np.intp)
    jmax = int(r_steps.max()) + 1
    offsets = np.arange(-jmax, jmax + 1) * _STEP
    contrast: np.ndarray = np.zeros((S, K))
    valid = present
    for _ in range(max(passes, 1)):
        s0 = model.offset(t)
        prof = _profiles(lin, a, u, n, t, s0, offsets)
        off, valid, contrast = _area_offsets(prof, r_steps, jmax, min_contrast)
        valid &= present
        model.fit(t, s0 + off, valid, min_sigma_px=0.01, reject_sigmas=3.0)
    _drop_flat_parabolas(model, lambda: model.fit(t, s0 + off, valid, min_sigma_px=0.01,
                                                  reject_sigmas=3.0))
    med = np.nanmedian(np.where(valid, contrast, np.nan), axis=1) if valid.any() \
        else np.zeros(S)
    return np.nan_to_num(med), valid


def model_bits(inner_same: np.ndarray) -> int:
    """Code cells per side of an ``inner_same`` array ((M, 4, bits) or (M, 4, rows, bits))."""
    return int(np.shape(inner_same)[-1])


def _drop_flat_parabolas(model: _SideModel, refit: Callable[[], None] | None) -> None:
    """Keep a parabola only where its curvature is significant (3 sigma)."""
    curved = model.order >= 3
    if not curved.any():
        return
    sd = np.sqrt(np.maximum(model.cov[:, 2, 2], 1e-30))
    keep = curved & (np.abs(model.coef[:, 2]) > 3.0 * sd)
    if (curved & ~keep).any():
        model.order = np.where(keep, 3, 2)
        if refit is not None:
            refit()
        else:
            model.coef[~keep, 2] = 0.0
            model.cov[~keep, 2, :] = 0.0
            model.cov[~keep, :, 2] = 0.0


def _model_passes(lin: np.ndarray, quads: np.ndarray, a: np.ndarray, u: np.ndarray,
                  n: np.ndarray, t: np.ndarray, present: np.ndarray, model: _SideModel,
                  module: np.ndarray, bits: int, inner_same: np.ndarray | None,
                  quiet_modules: float, passes: int, fit_order: np.ndarray,
                  lens: LensModel | DivisionLens | None = None,
                  corner_clear: float = 1.5, outer_same: np.ndarray | None = None,
                  beyond_modules: float = 1.0) -> np.ndarray:
    """Blurred-step model fits (see :mod:`detect_model`); updates ``model``; returns contrast.

    ``fit_order`` (S,) says per side whether the parabola term is free (3) or held
    at its current value (2: a straight line, or a lens-given bend). Samples inside
    the border must stay ``corner_clear`` pixels inside both neighbouring sides:
    near an acute corner (a steeply tilted marker) a cut straight inward from the
    side would otherwise leave the marker through its neighbour.
    """
    S = t.shape[0]
    M = S // 4
    contrast = np.zeros(S)
    blur = np.full(S, 0.8)
    for _ in range(max(passes, 1)):
        corners, _ = _intersect(model, a, u, n, M)
        bad = ~np.isfinite(corners).all(axis=(1, 2))
        corners[bad] = quads[bad]
        s0 = model.offset(t)
        base = a[:, None, :] + t[..., None] * u[:, None, :] + s0[..., None] * n[:, None, :]
        _, m_px = _module_geometry_at(corners, base.reshape(-1, 2),
                                      np.repeat(np.arange(S), base.shape[1]), n, bits)
        m_px = m_px.reshape(base.shape[:2])
        psid = np.nonzero(present)[0]
        pslot, pP = side_slots(psid, S)
        m_med = np.nan_to_num(side_median(m_px[present], np.ones(len(psid), bool), psid,
                                          pslot, S, pP), nan=1.0)
        rows = 0 if inner_same is None else int(np.shape(inner_same)[2])
        if rows == 0:
            inner = np.clip(m_med - 1.0, 1.0, 5.0)
        else:
            inner = np.clip(np.minimum(rows * m_med + 2.0, (rows + 1) * m_med - 1.5), 1.0, 5.0)
        outer = np.clip(quiet_modules * m_med - 1.2, 1.5, 5.0)
        known = None
        if outer_same is not None:
            known = np.asarray(outer_same, bool).reshape(S)
            reach = np.clip((quiet_modules + beyond_modules) * m_med - 1.2, 1.5, 5.0)
            outer = np.where(known, np.maximum(reach, outer), outer)
        # samples: the pixels nearest a grid of points along and across each side, so
        # the model sees raw pixel values (interpolation would add its own, phase-
        # dependent edge shifts)
        offsets = np.arange(-np.ceil(inner.max()), np.ceil(outer.max()) + 1.0)
        pts = base[:, :, None, :] + offsets[None, None, :, None] * n[:, None, None, :]
        h, w = lin.shape
        px = np.clip(np.rint(pts[..., 0]), 0, w - 1)
        py = np.clip(np.rint(pts[..., 1]), 0, h - 1)
        rel_x = px - a[:, None, None, 0]
        rel_y = py - a[:, None, None, 1]
        t_s = rel_x * u[:, None, None, 0] + rel_y * u[:, None, None, 1]
        s_s = rel_x * n[:, None, None, 0] + rel_y * n[:, None, None, 1]
        e_s = model.offset(t_s.reshape(S, -1)).reshape(t_s.shape)
        on_image = ((pts[..., 0] > -0.5) & (pts[..., 0] < w - 0.5)
                    & (pts[..., 1] > -0.5) & (pts[..., 1] < h - 0.5))
        mask = (present[..., None] & on_image & (s_s - e_s >= -inner[:, None, None])
                & (s_s - e_s <= outer[:, None, None])
                & ((s_s - e_s >= 0.0) | _clear_of_neighbours(corners, px, py, corner_clear)))
        # from here on only the samples used, flat and grouped by side
        sid = np.nonzero(mask)[0]
        px_c, py_c, t_c, s_c = px[mask], py[mask], t_s[mask], s_s[mask]
        values = lin[py_c.astype(np.intp), px_c.astype(np.intp)].astype(np.float64)
        basis = model.basis_at(t_c, sid)
        along, m_s = _module_geometry_at(corners, np.stack([px_c, py_c], axis=-1), sid, n,
                                         bits, lens)
        if rows:
            blur_modules = (blur * (bits + 2) / model.length)[sid]
            same = np.asarray(inner_same, bool).reshape(S, rows, bits)[sid]
            far = np.stack([_far_cells(along.astype(np.float32), same[:, r],
                                       blur_modules.astype(np.float32))
                            for r in range(rows)], axis=-1)
        else:
            far = np.zeros((len(sid), 1), dtype=np.float32)
        coef, cov, blur, rms = fit_step_model(
            values, s_c, sid, S, basis, model.coef, far, m_s, fit_order, n,
            outer=None if known is None else known[sid].astype(np.float32),
            quiet_px=None if known is None else quiet_modules * m_s)
        model.coef = coef
        model.cov = cov
        model.rms = rms
        model.count = mask.any(axis=2).sum(axis=1).astype(np.intp)
        rel = s_c - np.einsum("np,np->n", basis, coef[sid])
        slot, P = side_slots(sid, S)
        with np.errstate(all="ignore"):
            hi = side_median(values, rel > 0.7, sid, slot, S, P)
            lo = side_median(values, rel < -0.7, sid, slot, S, P)
        contrast = np.abs(np.nan_to_num(hi - lo))
    return contrast


def _clear_of_neighbours(corners: np.ndarray, px: np.ndarray, py: np.ndarray,
                         clear: float) -> np.ndarray:
    """(S, ...) bool: points (px, py) of each side at least ``clear`` inside its two neighbours.

    Args:
        corners: (M, 4, 2) current quads; side k runs from corner k to k+1.
        px, py: (S, ...) point coordinates, S = 4 M, grouped by side.
    """
    start, _, outward, _ = _side_frames(corners)
    M = len(corners)
    start, inward = start.reshape(M, 4, 2), -outward.reshape(M, 4, 2)
    extra = (1,) * (px.ndim - 1)
    ok = np.ones(px.shape, dtype=bool)
    for shift in (-1, 1):  # the previous and the next side
        p0 = np.roll(start, -shift, axis=1).reshape(4 * M, 2)
        nin = np.roll(inward, -shift, axis=1).reshape(4 * M, 2)
        dist = ((px - p0[:, 0].reshape(-1, *extra)) * nin[:, 0].reshape(-1, *extra)
                + (py - p0[:, 1].reshape(-1, *extra)) * nin[:, 1].reshape(-1, *extra))
        ok &= dist >= clear
    return ok

def _lens_bend(lens: LensModel | DivisionLens, a: np.ndarray, u: np.ndarray, n: np.ndarray,
               length: np.ndarray) -> np.ndarray:
    """(S,) parabola coefficient of the image of a straight edge between each side's ends.

    The chord's midpoint is mapped to straightened pixels, where the edge is
    straight, and back; its offset along the normal is the sag, and the
    parabola term (tau^2 - 1/3) of the fitted offset is minus the sag.
    """
    p0 = a
    p1 = a + length[:, None] * u
    und = lens.undistort(np.concatenate([p0, p1]))
    mid_u = 0.5 * (und[: len(a)] + und[len(a):])
    mid_d = lens.distort(mid_u)
    sag = np.einsum("sd,sd->s", mid_d - 0.5 * (p0 + p1), n)
    return -np.nan_to_num(sag)


def _module_geometry_at(corners: np.ndarray, pts: np.ndarray, side: np.ndarray,
                        n: np.ndarray, bits: int,
                        lens: LensModel | DivisionLens | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Along-side position (in modules, 0..bits+2) and local module width (pixels).

    Args:
        corners: (M, 4, 2) current quads.
        pts: (N, 2) image points, each belonging to side ``side`` (N,) of a marker.
        n: (S, 2) outward normals.

    With a lens the marker's homography is taken between undistorted pixels, so
    the code cells land where the lens puts them (near the corners of a strongly
    distorted image, the distorted quad's homography misplaces them by up to a
    pixel along the side).
    """
    size = bits + 2.0
    marker = side // 4
    inward = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])
    k = side % 4
    if lens is None:
        H = module_homographies(corners, bits)
        mod = _apply_each(np.linalg.inv(H), marker, pts)
        inner = _apply_each(H, marker, mod + inward[k])
    else:
        M = len(corners)
        H = module_homographies(lens.undistort(corners.reshape(-1, 2)).reshape(M, 4, 2), bits)
        mod = _apply_each(np.linalg.inv(H), marker, lens.undistort(pts))
        inner = lens.distort(_apply_each(H, marker, mod + inward[k]))
    m_px = np.einsum("nd,nd->n", pts - inner, n[side])
    along = np.where(k % 2 == 0, mod[:, 0], mod[:, 1])
    along = np.where(k >= 2, size - along, along)  # in side direction
    return along, np.clip(m_px, 0.5, None)


def _apply_each(H: np.ndarray, which: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply homography ``H[which[i]]`` ((M, 3, 3), which (N,)) to each point (N, 2)."""
    h = [np.take(col, which) for col in np.ascontiguousarray(H.reshape(-1, 9).T)]
    x, y = pts[:, 0], pts[:, 1]
    w = h[6] * x + h[7] * y + h[8]
    with np.errstate(all="ignore"):
        return np.stack([(h[0] * x + h[1] * y + h[2]) / w, (h[3] * x + h[4] * y + h[5]) / w],
                        axis=1)


def _far_cells(along: np.ndarray, same: np.ndarray, blur_modules: np.ndarray) -> np.ndarray:
    """(S, K) weight c of the far edge for every profile, blurred along the side.

    Gaussian blur is separable, so behind a straight border the code cells'
    contribution at along-side position x is the sum over cells of the other
    colour of ``Phi((x - x0) / w) - Phi((x - x1) / w)``.

    Args:
        along: (S, ...) position along each side, modules (0 .. bits + 2).
        same: (S, bits) bool, code cells of one row behind the border that share its colour.
        blur_modules: (S, 1, ...) blur per side, in modules along the side.
    """
    bits = same.shape[1]
    w = np.maximum(blur_modules, 1e-3)
    far = np.zeros_like(along)
    extra = (1,) * (along.ndim - 1)
    # CDF at each cell boundary once; cell i spans boundaries i+1 .. i+2
    left = phi_cdf((along - 1.0) / w)
    for i in range(bits):
        right = phi_cdf((along - (i + 2)) / w)
        other = (~same[:, i]).astype(np.float64).reshape(-1, *extra)
        far += other * (left - right)
        left = right
    return far


def _clean_profiles(t: np.ndarray, length: np.ndarray, same: np.ndarray) -> np.ndarray:
    """(S, K) bool: profiles whose neighbourhood along the side has border-coloured cells inside.

    Args:
        t: (S, K) along-side positions, pixels.
        length: (S,) side lengths, pixels.
        same: (S, bits) bool, code cells next to the border, in side order.
    """
    bits = same.shape[1]
    pos = t / length[:, None] * (bits + 2) - 1.0  # in code cells, 0..bits along the code
    ok = np.ones(t.shape, dtype=bool)
    for delta in (-0.4, 0.0, 0.4):
        cell = np.floor(pos + delta).astype(np.intp)
        inside = (cell >= 0) & (cell < bits)
        hit = np.take_along_axis(same, np.clip(cell, 0, bits - 1), axis=1)
        ok &= ~inside | hit
    return ok


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


def _straight_in_undistorted(lens: LensModel | DivisionLens, a: np.ndarray, u: np.ndarray,
                             n: np.ndarray,
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


def _side_curvature(lens: DivisionLens, pts: np.ndarray, quads: np.ndarray,
                    valid: np.ndarray) -> np.ndarray:
    """(S,) parabola coefficient of every side's edge points after straightening by ``lens``."""
    M = len(quads)
    und = lens.undistort(pts.reshape(-1, 2)).reshape(pts.shape)
    ua, uu, un, ul = _side_frames(lens.undistort(quads.reshape(-1, 2)).reshape(M, 4, 2))
    rel = und - ua[:, None, :]
    t = np.einsum("skd,sd->sk", rel, uu)
    s = np.einsum("skd,sd->sk", rel, un)
    # one unweighted least-squares parabola per side (what _SideModel.fit's first
    # step does), without the robust rescaling and covariance that are not used here
    A = _SideModel(ul, np.full(len(ul), 3)).basis(t)
    w = valid.astype(np.float64)
    AtW = A * w[..., None]
    N = np.matmul(AtW.transpose(0, 2, 1), A) + 1e-9 * np.eye(3)
    rhs = np.matmul(AtW.transpose(0, 2, 1), np.where(valid, s, 0.0)[..., None])
    return np.linalg.solve(N, rhs)[:, 2, 0]


def _division(theta: np.ndarray, centre: np.ndarray, scale: float) -> DivisionLens:
    """The division lens of parameters (lam, lam2, lam3)."""
    return DivisionLens(float(theta[0]), centre, scale, float(theta[1]), float(theta[2]))


def _estimate_division(model: _SideModel, quads: np.ndarray, t: np.ndarray,
                       valid: np.ndarray, shape: tuple[int, ...],
                       pool: LensPool | None = None) -> DivisionLens | None:
    """Plumb-line estimate of a division-model lens from all sides' curvature.

    The board's edges are straight, so whatever bends them all in a consistent
    radial way is lens distortion. The parabola term of every side is, to first
    order, linear in the division parameters; weighted least squares (three
    Gauss-Newton steps, weak zero-mean priors that shrink poorly determined
    parameters towards no distortion) gives them. Returns None without enough
    curved sides or with an implausible estimate; the result's ``significance``
    says how well the r^2 term is determined.
    With a ``pool``, earlier frames' evidence joins the fit and this frame's is added.
    """
    if pool is not None and pool.shape != tuple(shape[:2]):
        pool.reset(tuple(shape[:2]))
    pooled_info = pool.info if pool is not None else np.zeros((3, 3))
    pooled_rhs = pool.info_theta if pool is not None else np.zeros(3)
    if not (model.order >= 3).any() and not pooled_info.any():
        return None
    h, w = shape[:2]
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    scale = float(np.hypot(w, h) / 2.0)
    a, u, n, _ = _side_frames(quads)
    pts = (a[:, None, :] + t[..., None] * u[:, None, :]
           + model.offset(t)[..., None] * n[:, None, :])
    use = (model.order >= 3) & (model.count >= 6)
    var = np.where(use, model.cov[:, 2, 2], np.inf) + 0.003**2
    weight = np.where(use, 1.0 / var, 0.0)
    theta: np.ndarray = np.zeros(3)  # lam, lam2, lam3
    eps = 1e-3
    # weak priors keep the r^4 and r^6 terms at zero unless the sides really ask for them
    # (the r^6 term lets the model follow a polynomial lens's image corners)
    prior = np.diag([1.0 / 0.5**2, 1.0 / 0.3**2, 1.0 / 0.05**2])
    info: np.ndarray = np.zeros((3, 3))
    own_info: np.ndarray = np.zeros((3, 3))
    own_grad: np.ndarray = np.zeros(3)
    for _ in range(3):
        c = _side_curvature(_division(theta, centre, scale), pts, quads, valid)
        G = np.stack([(_side_curvature(_division(theta + eps * np.eye(3)[k], centre, scale),
                                       pts, quads, valid) - c) / eps for k in range(3)], axis=1)
        ok = use & np.isfinite(c) & np.isfinite(G).all(axis=1)
        if ok.sum() < 4 and not pooled_info.any():
            return None
        Wg = G[ok] * weight[ok, None]
        own_info = G[ok].T @ Wg
        own_grad = Wg.T @ c[ok]
        info = own_info + prior + pooled_info
        rhs = own_grad + (prior + pooled_info) @ theta - pooled_rhs
        try:
            theta = theta - np.linalg.solve(info, rhs)
        except np.linalg.LinAlgError:
            return None
    if pool is not None and np.isfinite(theta).all():
        # this frame's own estimate, linearised at theta: own_info^-1 (own_info theta - grad)
        pool.info = pool.info + own_info
        pool.info_theta = pool.info_theta + own_info @ theta - own_grad
    lam, lam2, lam3 = float(theta[0]), float(theta[1]), float(theta[2])
    sd = float(np.sqrt(max(np.linalg.inv(info)[0, 0], 1e-30)))
    if not np.isfinite(theta).all() or abs(lam) > 1.0 or abs(lam2) > 1.0 or abs(lam3) > 1.0:
        return None
    return DivisionLens(lam, centre, scale, lam2, lam3, abs(lam) / sd)
