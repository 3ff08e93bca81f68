"""Sub-pixel marker corners from fitted border edges (the ARTag way).

Each side of a marker's outer border is a step edge between the border and the
quiet zone around the marker. A first straight line per side comes from the
strongest gradient across it; then the raw pixels of a band across each side
are fitted with a blurred-step model (:mod:`artcal_ros.core.detect.step_model`:
the pixel's square footprint, a Gaussian blur per side, the code cells behind
the border from the decoded id). Sides are then, with a lens given or estimated
from the sides' curvature (plumb lines, :mod:`artcal_ros.core.detect.plumb`,
pooled over frames by :class:`~artcal_ros.core.detect.lens.LensPool`), bent
exactly as the lens bends a straight edge, and neighbouring sides are
intersected into corners (:mod:`artcal_ros.core.detect.sides`).

Why the image is read in *linear* intensity: a pixel integrates light, and the
gamma encoding comes afterwards. A blurred step is symmetric about the edge in
linear light, not in gamma-encoded grey values, so a grey-level midpoint of the
encoded image sits toward the dark side. The caller passes a linearised image.

All arrays are batched over the S = 4 M sides of M markers; side k of a marker
runs from its corner k to corner k+1 (TL->TR, TR->BR, BR->BL, BL->TL), so
corner k is the intersection of sides k-1 and k.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from artcal_ros.core.detect.lens import Lens, LensPool
from artcal_ros.core.detect.linalg import nanmedian_rows
from artcal_ros.core.detect.plumb import estimate_division, lens_bend
from artcal_ros.core.detect.profiles import coarse_offsets, gather_samples
from artcal_ros.core.detect.sides import (
    SideModel,
    intersect_sides,
    module_geometry_at,
    side_frames,
)
from artcal_ros.core.detect.step_model import far_cells, fit_step_model
from artcal_ros.core.homography import shortest_sides

__all__ = ["EdgeFit", "refine_quads", "same_edges"]

_STEP = 0.25  # profile sample spacing, pixels
# the blurred-step fit: Gauss-Newton steps of a side that starts from its frame's blur,
# and the edge movement below which a side stops early, pixels
_FIT_STEPS = 4
_FIT_TOL_PX = 3e-4
# one side in _PILOT_EVERY, fitted first (_PILOT_STEPS steps from 0.6 px), gives that blur
_PILOT_EVERY = 8
_PILOT_STEPS = 8
# a tone-curve probe re-fits the pilot sides from their fit, this many steps per curve
_PROBE_STEPS = 2


@dataclass(frozen=True)
class EdgeFit:
    """Result of refining M quads.

    Attributes:
        corners_px: (M, 4, 2) float64, pixels, refined corners in the input order.
        corner_sigma_px: (M, 4) float64, 1-sigma error of each corner per axis, pixels.
        ok: (M,) bool, every side had enough edge points for a fit.
        lens: the lens model the sides were bent by: the one given, one
            estimated from the edges' curvature (:class:`DivisionLens`), or None.
    """

    corners_px: np.ndarray
    corner_sigma_px: np.ndarray
    ok: np.ndarray
    lens: Lens | None = None


def refine_quads(lin: np.ndarray, quads: np.ndarray, dark_inside: np.ndarray, bits: int, *,
                 margin_px: float = 1.5, curve_min_px: float = 60.0,
                 allow_curvature: bool = True, passes: int = 2,
                 lens: Lens | None = None,
                 inner_same: np.ndarray | None = None,
                 quiet_modules: float = 1.0, outer_same: np.ndarray | None = None,
                 beyond_modules: float = 1.0, max_profiles: int = 40,
                 lens_pool: LensPool | None = None,
                 tone_probe: Callable[..., None] | None = None,
                 censor_at: float | None = None) -> EdgeFit:
    """Refine approximate quads to sub-pixel corners from their border edges.

    Args:
        lin: (H, W) float image in linear intensity (roughly 0..1).
        quads: (M, 4, 2) float64, approximate corners (within ~1.5 px), pixels.
        dark_inside: (M,) bool, True where the marker's border is darker than its
            surroundings (black-on-white).
        bits: code cells per side (the border adds two modules).
        margin_px: profiles closer than this to a corner are skipped (the other
            side's blur reaches there).
        curve_min_px: sides at least this long may be fitted with a parabola
            (kept only where its curvature is significant).
        allow_curvature: False fits straight lines only (use it when the image
            has been undistorted or a camera model handles distortion).
        passes: re-centered passes of the model fit.
        lens: optional lens model; every side is then bent as the lens bends a
            straight edge, and only its offset and angle are fitted.
        inner_same: optional (M, 4, rows, bits) bool (see
            :func:`~artcal_ros.core.detect.patterns.inner_border_cells`): per side,
            the code cells of the first rows behind the border (in side order)
            that have the border's colour. The model fit uses them to model the
            code's edges behind the border; without them the window stops short
            of the code.
        quiet_modules: width of the quiet zone outside the border, in modules.
        outer_same: optional (M, 4) bool, per side: the board has a known edge back
            to the border's colour at the quiet zone's end (the neighbouring tile
            of a mixed board). The model fit then models that edge and reaches up
            to ``beyond_modules`` past it; without it the window stops short of
            the quiet zone's end.
        beyond_modules: how far past a known outer edge the window reaches, modules.
        max_profiles: most profiles per side (long sides are sampled sparser).
        lens_pool: evidence about the lens from earlier frames of the same camera
            (used and extended when the lens is estimated here).
        tone_probe: optional ``tone_probe(probe_fit)``, called with a :class:`ProbeFit`
            after every pass's fit; the last call is the final fit's (see
            :func:`~artcal_ros.core.detect.tone.probe_costs`).
        censor_at: optional saturation level of ``lin``: saturated samples are censored
            in the model fit (see :func:`~artcal_ros.core.detect.step_model.fit_step_model`).

    Returns:
        the :class:`EdgeFit`.
    """
    M = len(quads)
    if M == 0:
        return EdgeFit(np.zeros((0, 4, 2)), np.zeros((0, 4)), np.zeros(0, dtype=bool))
    quads = np.asarray(quads, dtype=np.float64)
    lin = np.asarray(lin, dtype=np.float32)
    sign = np.repeat(np.where(dark_inside, 1.0, -1.0), 4)
    # coarse pass: strongest gradient near the approximate side. The quad finder's
    # contour runs through the pixels on the dark side of the border edge: up to a
    # pixel or two inside a black border, outside a white one.
    inward = np.where(sign > 0, 0.0, 1.5)
    _, _, _, length0 = side_frames(quads)
    reach = np.minimum(0.45 * length0 / (bits + 2), 4.0)
    model, t, present, a, u, n = _coarse_lines(lin, quads, sign, -reach - inward,
                                               reach + 1.5 - inward, margin_px,
                                               max_profiles)
    # the profiles, the windows and the along-side margins are then laid out again
    # from the quad those lines give: the quad finder's corners can be a pixel or two
    # off, which puts the margins (and the model's code cells) in the wrong place
    coarse, _ = intersect_sides(model, a, u, n, M)
    quads = np.where(same_edges(coarse, quads)[:, None, None], coarse, quads)
    model, t, present, a, u, n = _coarse_lines(lin, quads, sign, np.full(4 * M, -1.0),
                                               np.full(4 * M, 1.0), margin_px, max_profiles)
    length = model.length
    S = len(a)
    order = np.where(allow_curvature & (length >= curve_min_px), 3, 2)
    model.order = order

    # lines (parabolas on long sides when curvature is allowed); then, with a lens
    # given or estimated from those parabolas, every side bent as the lens bends a
    # straight edge and only its offset and angle fitted.
    # With the lens still to be estimated from this pass's free parabolas, the
    # edge beyond a narrow quiet zone waits for the lens-aware pass below.
    used_lens: Lens | None = lens
    later = lens is None and allow_curvature
    fit_blur = _model_passes(lin, quads, a, u, n, t, present, model, bits, inner_same,
                             quiet_modules, passes, order, None, margin_px,
                             None if later else outer_same, beyond_modules,
                             tone_probe=tone_probe, censor_at=censor_at)
    if later:
        used_lens = estimate_division(model, quads, t, present, lin.shape, pool=lens_pool)
    if used_lens is not None:
        model.order = np.full(S, 3)
        model.coef[:, 2] = lens_bend(used_lens, a, u, n, length)
        _model_passes(lin, quads, a, u, n, t, present, model, bits, inner_same,
                      quiet_modules, 1, np.full(S, 2), used_lens, margin_px, outer_same,
                      beyond_modules, fit_blur, tone_probe=tone_probe, censor_at=censor_at)
    else:
        _drop_flat_parabolas(model)
        if later and outer_same is not None:
            _model_passes(lin, quads, a, u, n, t, present, model, bits, inner_same,
                          quiet_modules, 1, model.order, None, margin_px, outer_same,
                          beyond_modules, fit_blur, tone_probe=tone_probe,
                          censor_at=censor_at)
    corners, sigma = intersect_sides(model, a, u, n, M)
    side_ok = model.count >= 4
    ok = side_ok.reshape(M, 4).all(axis=1) & np.isfinite(corners).all(axis=(1, 2))
    return EdgeFit(corners, sigma, ok, used_lens)


def same_edges(new: np.ndarray, old: np.ndarray) -> np.ndarray:
    """(M,) bool: refined quads (M, 4, 2) still on the edges of the quads they came from.

    The quad finder's polygon can be a few pixels off on large, bent markers;
    a corner that moved further than 3 px and a tenth of the shortest side has
    found a different edge (NaN corners fail too).

    Args:
        new: (M, 4, 2) refined corners, pixels.
        old: (M, 4, 2) the corners they were refined from, pixels.
    """
    moved = np.abs(new - old).max(axis=(1, 2))
    return np.asarray(moved < np.maximum(3.0, 0.1 * shortest_sides(old)))


def _coarse_lines(lin: np.ndarray, quads: np.ndarray, sign: np.ndarray, lo: np.ndarray,
                  hi: np.ndarray, margin_px: float, max_profiles: int
                  ) -> tuple[SideModel, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                             np.ndarray]:
    """Straight edge lines from the strongest gradient within [lo, hi] of each quad side.

    Also lays out the along-side profile positions: the same count K for every
    side (padded), ``margin_px`` clear of the corners.

    Args:
        lin: (H, W) linear intensity image.
        quads: (M, 4, 2) approximate corners, pixels.
        sign: (S,) +1 where intensity rises outward (dark border), -1 where it falls.
        lo, hi: (S,) search window along each side's normal, pixels.
        margin_px: along-side clearance from the corners, pixels.
        max_profiles: most profiles per side.

    Returns:
        the line model, t (S, K), present (S, K), and the side frames a, u, n.
    """
    a, u, n, length = side_frames(quads)
    usable = np.maximum(length - 2.0 * margin_px, 0.0)
    k_side = np.clip(np.round(usable).astype(np.intp), 0, max_profiles)
    K = max(int(k_side.max()), 1)
    kk = np.arange(K)[None, :]
    t = margin_px + (kk + 0.5) / np.maximum(k_side[:, None], 1) * usable[:, None]
    present = kk < k_side[:, None]
    model = SideModel(length, np.full(len(a), 2))
    # every other profile is enough for a first line
    tc, pc = t[:, ::2], present[:, ::2]
    first = min(float(lo.min()), 0.0) - 1.0
    last = max(float(hi.max()), 0.0) + 1.0
    offsets: np.ndarray = np.arange(first, last + 1e-9, 2 * _STEP)
    s_edge, valid = coarse_offsets(lin, a, u, n, tc, offsets, sign, lo, hi)
    model.fit(tc, s_edge, valid & pc, min_sigma_px=0.05, reject_sigmas=3.0)
    return model, t, present, a, u, n


def _drop_flat_parabolas(model: SideModel) -> None:
    """Keep a parabola only where its curvature is significant (3 sigma); updates ``model``."""
    curved = model.order >= 3
    if not curved.any():
        return
    sd = np.sqrt(np.maximum(model.cov[:, 2, 2], 1e-30))
    keep = curved & (np.abs(model.coef[:, 2]) > 3.0 * sd)
    if (curved & ~keep).any():
        model.order = np.where(keep, 3, 2)
        model.coef[~keep, 2] = 0.0
        model.cov[~keep, 2, :] = 0.0
        model.cov[~keep, :, 2] = 0.0


def _model_passes(lin: np.ndarray, quads: np.ndarray, a: np.ndarray, u: np.ndarray,
                  n: np.ndarray, t: np.ndarray, present: np.ndarray, model: SideModel,
                  bits: int, inner_same: np.ndarray | None,
                  quiet_modules: float, passes: int, fit_order: np.ndarray,
                  lens: Lens | None = None,
                  corner_clear: float = 1.5, outer_same: np.ndarray | None = None,
                  beyond_modules: float = 1.0, start_blur: np.ndarray | None = None,
                  tone_probe: Callable[..., None] | None = None,
                  censor_at: float | None = None) -> np.ndarray:
    """Blurred-step model fits (see :mod:`~artcal_ros.core.detect.step_model`); updates ``model``.

    ``fit_order`` (S,) says per side whether the parabola term is free (3) or held
    at its current value (2: a straight line, or a lens-given bend). Samples inside
    the border must stay ``corner_clear`` pixels inside both neighbouring sides:
    near an acute corner (a steeply tilted marker) a cut straight inward from the
    side would otherwise leave the marker through its neighbour.

    Args:
        lin: (H, W) float32 linear intensity image.
        quads: (M, 4, 2) the quads the sides were laid out from (fallback corners), pixels.
        a, u, n: (S, 2) side frames; t, present: (S, K) profile positions and mask.
        model: the side model to refine (its coefficients are the start).
        bits, inner_same, quiet_modules, outer_same, beyond_modules: as for
            :func:`refine_quads`.
        passes: model fits, each re-centered on the previous one.
        fit_order: (S,) see above.
        lens: optional lens (places the code cells along each side).
        corner_clear: see above, pixels.
        start_blur: (S,) the blur the model fit starts from (an earlier pass's), pixels;
            without, the frame's blur from a pilot fit of every 8th side.
        tone_probe, censor_at: see :func:`refine_quads`.

    Returns:
        (S,) the fitted blur, pixels.
    """
    S = t.shape[0]
    M = S // 4
    blur = np.full(S, 0.8)  # along the side, for the code cells
    fit_blur = start_blur
    for _ in range(max(passes, 1)):
        corners, _ = intersect_sides(model, a, u, n, M)
        bad = ~np.isfinite(corners).all(axis=(1, 2))
        corners[bad] = quads[bad]
        s0 = model.offset(t)
        base = a[:, None, :] + t[..., None] * u[:, None, :] + s0[..., None] * n[:, None, :]
        _, m_px = module_geometry_at(corners, base.reshape(-1, 2),
                                     np.repeat(np.arange(S), base.shape[1]), n, bits)
        m_px = m_px.reshape(base.shape[:2])
        m_med = np.nan_to_num(nanmedian_rows(np.where(present, m_px, np.nan)), nan=1.0)
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
        # samples: the pixels nearest a grid of points along and across each side (raw
        # values: interpolation would add its own, phase-dependent edge shifts)
        span = (-int(np.ceil(inner.max())), int(np.ceil(outer.max())))
        samples, basis, sid, used = gather_samples(
            lin, a, u, n, t, present, model.coef, model.length, model.order >= 3, span, inner,
            outer, _neighbour_lines(corners), corner_clear)
        px_c, py_c, _, s_c, values, rel = samples
        pts_c = np.stack([px_c, py_c], axis=-1)    # (the border's width places the code)
        along, m_s = module_geometry_at(corners, pts_c, sid, n, bits, lens, offset=rel)
        # (a mixed board's known edge beyond the quiet zone: better by the sample's width)
        quiet_m = m_s if known is None else module_geometry_at(corners, pts_c, sid, n,
                                                               bits, lens)[1]
        if rows:
            far = far_cells(along, sid, np.asarray(inner_same, bool).reshape(S, rows, bits),
                            blur * (bits + 2) / model.length)
        else:
            far = np.zeros((len(sid), 1), dtype=np.float32)
        common: dict[str, Any] = dict(
            s=s_c, side=sid, n_sides=S, basis=basis, far=far, module_px=m_s,
            fit_order=fit_order, normal=n, tol_px=_FIT_TOL_PX,
            outer=None if known is None else known[sid].astype(np.float32),
            quiet_px=None if known is None else quiet_modules * quiet_m, censor_at=censor_at)

        def fit(vals: np.ndarray = values, coef0: np.ndarray = model.coef,
                common: dict[str, Any] = common,
                **kw: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            return fit_step_model(vals, coef0=coef0, **common, **kw)

        if fit_blur is None:
            # the frame's blur from a few sides first: the others then start close to
            # theirs (blur hardly varies across a frame; 0.6 px is far from a sharp
            # edge's 0.03) and need a few steps, not 5 - 8
            few = np.flatnonzero(used > 0)[::_PILOT_EVERY]
            pilot = fit(blur0=np.full(S, 0.6), iterations=_PILOT_STEPS, sides=few)[2]
            fit_blur = np.full(S, float(np.median(pilot[few])) if len(few) else 0.6)
        contrast = np.zeros(S)
        coef, cov, fit_blur = fit(blur0=fit_blur, iterations=_FIT_STEPS, contrast_out=contrast)
        if censor_at is not None and rows:
            # (only sides that are clipped: a frame may be clipped away from the board)
            clipped = np.bincount(sid, weights=values >= censor_at, minlength=S) >= 3
            coef, cov, fit_blur = _refit_lone_edges(fit, coef, cov, fit_blur, contrast,
                                                    np.asarray(inner_same, bool),
                                                    used * clipped)
        if tone_probe is not None:
            few = np.flatnonzero(used > 0)[::_PILOT_EVERY]
            if len(few):
                tone_probe(ProbeFit(common, values, few, coef, fit_blur))
        blur = fit_blur
        model.coef = coef
        model.cov = cov
        model.count = used
    assert fit_blur is not None  # passes >= 1
    return fit_blur


# sides with between these shares of the other colour behind their border show their
# blur and contrast (see _refit_lone_edges)
_HELD_BELOW, _HELD_ABOVE = 0.3, 0.6


def _refit_lone_edges(fit: Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]],
                      coef: np.ndarray, cov: np.ndarray, blur: np.ndarray,
                      contrast: np.ndarray, inner_same: np.ndarray, used: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clipped sides fitted again with the blur and contrast the well-placed ones show.

    With the paper clipped, a side sees the unclipped tails of its transitions only. A
    side with about as many code cells of the other colour behind its border as of its
    own shows two: the border's edge and, one module further in, the code cells' edge,
    with the same blur and contrast, which pins both down. One with (almost) only its
    own colour behind shows one tail, which cannot separate its position from its blur
    and hidden contrast; one with (almost) only the other colour has its border eaten
    from both sides, and its dark core no longer reaches the ink. So every clipped side
    is fitted again holding the blur at the median of the frame's two-transition sides
    (one lens, one focus) and the contrast at the median of its marker's (one paper, one
    light; the frame's when the marker has none): only its position and dark level are
    left free, and the four sides of a marker are placed alike.

    Args:
        fit: the pass's fit (``fit(**kw)``, see :func:`_model_passes`).
        coef, cov, blur, contrast: (S, 3), (S, 3, 3), (S,), (S,) the censored fit.
        inner_same: (M, 4, rows, bits) bool, see :func:`refine_quads`.
        used: (S,) samples each side had (0: the side takes no part).

    Returns:
        coef, cov, blur with those sides fitted again.
    """
    M = inner_same.shape[0]
    other = (~inner_same[:, :, 0, :]).mean(axis=2)          # (M, 4)
    part = used.reshape(M, 4) > 0
    held = part & ((other < _HELD_BELOW) | (other > _HELD_ABOVE))
    donor = part & ~held
    if not donor.any():
        return coef, cov, blur
    b4, c4 = blur.reshape(M, 4), contrast.reshape(M, 4)
    # contrast by magnitude: a white-bordered marker's is negative
    d_m = np.full(M, np.median(np.abs(c4[donor])))
    own = donor.any(axis=1)
    d_m[own] = np.nanmedian(np.where(donor, np.abs(c4), np.nan)[own], axis=1)
    # (the sign by the marker's majority: a side's own fit may have flipped it)
    sign = np.where(np.where(part, np.sign(c4), 0.0).sum(axis=1) < 0, -1.0, 1.0)
    hold_w = np.where(part, np.median(b4[donor]), 0.0)
    hold_d = np.where(part, (sign * d_m)[:, None], np.nan)
    sides = np.flatnonzero(part.ravel())
    c2, v2, b2 = fit(coef0=coef, blur0=blur, iterations=_FIT_STEPS, sides=sides,
                     hold_blur=hold_w.ravel(), hold_contrast=hold_d.ravel())
    coef, cov, blur = coef.copy(), cov.copy(), blur.copy()
    coef[sides], cov[sides], blur[sides] = c2[sides], v2[sides], b2[sides]
    return coef, cov, blur


# the step model's per-sample inputs (the others are per side)
_PER_SAMPLE = ("s", "side", "basis", "far", "module_px", "outer", "quiet_px")
_PER_SIDE = ("fit_order", "normal")


@dataclass(frozen=True)
class ProbeFit:
    """A pass's final step-model fit, kept so a tone probe can re-fit some of its sides.

    Attributes:
        common: the fit's inputs other than the values (:func:`fit_step_model`'s keywords).
        values: (N,) the samples' linear values.
        sides: (F,) int, the sides a probe may re-fit (every 8th fitted side).
        coef, blur: (S, 3), (S,) the fit.
    """

    common: dict[str, Any]
    values: np.ndarray
    sides: np.ndarray
    coef: np.ndarray
    blur: np.ndarray

    def subset(self, sides: np.ndarray, copies: int = 1
               ) -> tuple[Callable[..., None], np.ndarray]:
        """``fit_values(values, **kw)`` on ``copies`` copies of only ``sides``' samples,
        and those samples' values (one copy).

        The copies are one fit problem of ``copies * F`` sides (copy c's side f is
        side ``c F + f``; ``values``, ``coef0``, ``blur0`` and ``cost_out`` come in that
        order), so a probe of several curves is one call of the compiled fit, and the
        re-fits touch none of the frame's other samples.
        """
        # the samples are ordered by side: each side's are one run
        side = np.asarray(self.common["side"])
        sides = np.asarray(sides)
        lo = np.searchsorted(side, sides)
        hi = np.searchsorted(side, sides, side="right")
        keep = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)]
                              + [np.zeros(0, np.intp)])
        f = len(sides)
        local = np.repeat(np.arange(f), hi - lo)   # the kept samples' side, renumbered
        sub: dict[str, Any] = {}
        for k, v in self.common.items():
            if k == "side":
                sub[k] = np.concatenate([local + c * f for c in range(copies)])
            elif k in _PER_SAMPLE and v is not None:
                part = np.asarray(v)[keep]
                sub[k] = np.concatenate([part] * copies)
            elif k in _PER_SIDE:
                sub[k] = np.concatenate([np.asarray(v)[sides]] * copies)
            elif k == "n_sides":
                sub[k] = copies * f
            else:
                sub[k] = v

        def fit_values(values: np.ndarray, **kw: Any) -> None:
            fit_step_model(values, iterations=_PROBE_STEPS, **sub, **kw)

        return fit_values, self.values[keep]


def _neighbour_lines(corners: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A point (S, 2, 2) on, and the inward normal (S, 2, 2) of, each side's two neighbours.

    Index 0 is the previous side, 1 the next one, of the marker's quad (M, 4, 2).
    """
    start, _, outward, _ = side_frames(corners)
    M = len(corners)
    start, inward = start.reshape(M, 4, 2), -outward.reshape(M, 4, 2)
    p0 = np.stack([np.roll(start, -shift, axis=1).reshape(4 * M, 2) for shift in (-1, 1)], 1)
    nin = np.stack([np.roll(inward, -shift, axis=1).reshape(4 * M, 2) for shift in (-1, 1)], 1)
    return p0, nin
