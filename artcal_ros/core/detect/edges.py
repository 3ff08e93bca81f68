"""Sub-pixel marker corners from fitted border edges (the ARTag way).

A first straight line per side of a marker's border comes from the strongest gradient
across it; then the raw pixels of a band across each side are fitted with a blurred-step
model (:mod:`.step_model`: the pixel's footprint, a Gaussian blur per side, the code cells
behind the border from the decoded id). With a lens given or estimated from the sides'
curvature (:mod:`.plumb`, pooled by :class:`~.lens.LensPool`) the sides are bent as the
lens bends a straight edge, and neighbouring sides are intersected into corners
(:mod:`.sides`).

The image is read in *linear* intensity: a blurred step is symmetric about its edge in
linear light, not in gamma-encoded grey values. The caller passes a linearised image.

All arrays are batched over the S = 4 M sides of M markers; side k of a marker runs from
its corner k to corner k+1 (TL->TR, TR->BR, BR->BL, BL->TL): corner k joins sides k-1, k.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import partial
from typing import Any

import numpy as np

from artcal_ros.core.detect.bends import drop_flat_parabolas, trusted_bends
from artcal_ros.core.detect.lens import Lens, LensPool
from artcal_ros.core.detect.light import fit_in_light, in_light
from artcal_ros.core.detect.linalg import nanmedian_rows
from artcal_ros.core.detect.plumb import estimate_division, lens_bend
from artcal_ros.core.detect.profiles import coarse_offsets, gather_samples, sample_geometry
from artcal_ros.core.detect.sides import (
    SideModel,
    far_cells,
    intersect_sides,
    module_geometry_at,
    neighbour_lines,
    side_frames,
)
from artcal_ros.core.detect.step_model import StepSamples, fit_step_model
from artcal_ros.core.homography import shortest_sides

__all__ = ["EdgeFit", "EdgeFitSettings", "ProbeFit", "refine_quads", "same_edges"]

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


@dataclass(frozen=True)
class EdgeFitSettings:
    """How :func:`refine_quads` fits the sides of one call's quads.

    Attributes:
        bits: code cells per marker side (the border adds two modules).
        margin_px: profiles closer than this to a corner are skipped (the other side's
            blur reaches there), and samples inside the border stay this far inside both
            neighbouring sides, pixels.
        curve_min_px: sides at least this long may be fitted with a parabola (kept only
            where its curvature is significant), pixels.
        allow_curvature: False fits straight lines only (the image is undistorted, or a
            camera model handles distortion).
        passes: re-centred passes of the first model fit.
        quiet_modules: width of the quiet zone outside the border, modules.
        beyond_modules: how far past a known outer edge the window reaches, modules.
        max_profiles: most profiles per side (long sides are sampled sparser).
        censor_at: saturation level of the linear image: samples at or above it are
            censored in the model fit (None: none are).
        light_field: sides refitted in the frame's light field (:mod:`.light`).
    """

    bits: int
    margin_px: float = 1.5
    curve_min_px: float = 60.0
    allow_curvature: bool = True
    passes: int = 2
    quiet_modules: float = 1.0
    beyond_modules: float = 1.0
    max_profiles: int = 40
    censor_at: float | None = None
    light_field: bool = True


@dataclass(frozen=True)
class BorderCells:
    """What the board prints next to each side's border, from the decoded ids.

    Attributes:
        inner_same: (M, 4, rows, bits) bool or None: per side, the code cells of the first
            rows behind the border (in side order) that have the border's colour; the model
            fit models the code's edges from them (without: its window stops short of them).
        outer_same: (M, 4) bool or None: per side, the board has a known edge back to the
            border's colour where the quiet zone ends (the next tile of a mixed board); the
            fit models it and reaches ``beyond_modules`` past it (without: stops short).
    """

    inner_same: np.ndarray | None = None
    outer_same: np.ndarray | None = None


@dataclass(frozen=True)
class SideLayout:
    """Where each side's profiles lie (S = 4 M sides; see :mod:`.sides`).

    Attributes:
        quads: (M, 4, 2) the quads the sides were laid out from, pixels.
        a, u, n: (S, 2) each side's start (pixels), unit direction and outward unit normal.
        t: (S, K) the profiles' positions along their side, pixels.
        present: (S, K) bool, the profiles that exist (sides have up to K).
    """

    quads: np.ndarray
    a: np.ndarray
    u: np.ndarray
    n: np.ndarray
    t: np.ndarray
    present: np.ndarray


def refine_quads(lin: np.ndarray, quads: np.ndarray, dark_inside: np.ndarray, bits: int, *,
                 margin_px: float = 1.5, curve_min_px: float = 60.0,
                 allow_curvature: bool = True, passes: int = 2,
                 lens: Lens | None = None,
                 inner_same: np.ndarray | None = None,
                 quiet_modules: float = 1.0, outer_same: np.ndarray | None = None,
                 beyond_modules: float = 1.0, max_profiles: int = 40,
                 lens_pool: LensPool | None = None,
                 tone_probe: Callable[..., None] | None = None,
                 censor_at: float | None = None, light_field: bool = True) -> EdgeFit:
    """Refine approximate quads to sub-pixel corners from their border edges.

    Args:
        lin: (H, W) float image in linear intensity (roughly 0..1).
        quads: (M, 4, 2) float64, approximate corners (within ~1.5 px), pixels.
        dark_inside: (M,) bool, True where the marker's border is darker than its
            surroundings (black-on-white).
        bits, margin_px, curve_min_px, allow_curvature, passes, quiet_modules,
            beyond_modules, max_profiles, censor_at, light_field: see :class:`EdgeFitSettings`.
        lens: optional lens model; every side is then bent as the lens bends a
            straight edge, and only its offset and angle are fitted.
        inner_same, outer_same: see :class:`BorderCells` (from
            :func:`~artcal_ros.core.detect.patterns.inner_border_cells` and ``outer_neighbours``).
        lens_pool: evidence about the lens from earlier frames of the same camera
            (used and extended when the lens is estimated here).
        tone_probe: optional, called with a :class:`ProbeFit` after every pass's fit; the
            last call is the final fit's (see :func:`~artcal_ros.core.detect.tone.probe_costs`).

    Returns:
        the :class:`EdgeFit`.
    """
    M = len(quads)
    if M == 0:
        return EdgeFit(np.zeros((0, 4, 2)), np.zeros((0, 4)), np.zeros(0, dtype=bool))
    settings = EdgeFitSettings(bits, margin_px=margin_px, curve_min_px=curve_min_px,
                               allow_curvature=allow_curvature, passes=passes,
                               quiet_modules=quiet_modules, beyond_modules=beyond_modules,
                               max_profiles=max_profiles, censor_at=censor_at,
                               light_field=light_field)
    cells = BorderCells(inner_same, outer_same)
    quads = np.asarray(quads, dtype=np.float64)
    lin = np.asarray(lin, dtype=np.float32)
    sign = np.repeat(np.where(dark_inside, 1.0, -1.0), 4)
    # coarse pass: strongest gradient near the approximate side. The quad finder's
    # contour runs through the pixels on the dark side of the border edge: up to a
    # pixel or two inside a black border, outside a white one.
    inward = np.where(sign > 0, 0.0, 1.5)
    _, _, _, length0 = side_frames(quads)
    reach = np.minimum(0.45 * length0 / (bits + 2), 4.0)
    model, sides = _coarse_lines(lin, quads, sign, -reach - inward, reach + 1.5 - inward,
                                 settings)
    # the profiles, the windows and the along-side margins are then laid out again
    # from the quad those lines give: the quad finder's corners can be a pixel or two
    # off, which puts the margins (and the model's code cells) in the wrong place
    coarse, _ = intersect_sides(model, sides.a, sides.u, sides.n, M)
    quads = np.where(same_edges(coarse, quads)[:, None, None], coarse, quads)
    model, sides = _coarse_lines(lin, quads, sign, np.full(4 * M, -1.0), np.full(4 * M, 1.0),
                                 settings)
    S = len(sides.a)
    order = np.where(allow_curvature & (model.length >= curve_min_px), 3, 2)
    model.order = order

    # lines (parabolas on long sides when curvature is allowed); then, with a lens
    # given or estimated from those parabolas, every side bent as the lens bends a
    # straight edge and only its offset and angle fitted.
    # With the lens still to be estimated from this pass's free parabolas, the
    # edge beyond a narrow quiet zone waits for the lens-aware pass below.
    used_lens: Lens | None = lens
    later = lens is None and allow_curvature
    fit_blur, light = _model_passes(lin, sides, model, settings,
                                    replace(cells, outer_same=None) if later else cells,
                                    passes=passes, fit_order=order, tone_probe=tone_probe)
    if later:
        used_lens = estimate_division(model, quads, sides.t, sides.present, lin.shape,
                                      pool=lens_pool)
    if used_lens is not None:
        # (held where the lens is trusted; far out, mixed with the side's own parabola)
        used_lens, bend, bend_var = trusted_bends(
            lens_bend(used_lens, sides.a, sides.u, sides.n, model.length), used_lens, sides.a,
            sides.u, model.length, lin.shape, model if later else None, lens_pool)
        model.order, model.coef[:, 2] = np.full(S, 3), bend
        _model_passes(lin, sides, model, settings, cells, passes=1, fit_order=np.full(S, 2),
                      lens=used_lens, start_blur=fit_blur, light=light, tone_probe=tone_probe)
        model.cov[:, 2, 2] = bend_var  # the corners' sigmas carry the bend's
    else:
        drop_flat_parabolas(model)
        if later and outer_same is not None:
            _model_passes(lin, sides, model, settings, cells, passes=1,
                          fit_order=model.order, start_blur=fit_blur, light=light,
                          tone_probe=tone_probe)
    corners, sigma = intersect_sides(model, sides.a, sides.u, sides.n, M)
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
                  hi: np.ndarray, settings: EdgeFitSettings) -> tuple[SideModel, SideLayout]:
    """Straight edge lines from the strongest gradient within [lo, hi] of each quad side.

    Also lays out the along-side profile positions: the same count K for every
    side (padded), ``settings.margin_px`` clear of the corners.

    Args:
        lin: (H, W) linear intensity image.
        quads: (M, 4, 2) approximate corners, pixels.
        sign: (S,) +1 where intensity rises outward (dark border), -1 where it falls.
        lo, hi: (S,) search window along each side's normal, pixels.
        settings: the fit's settings (``margin_px``, ``max_profiles``).

    Returns:
        the line model and the sides' layout.
    """
    margin_px, max_profiles = settings.margin_px, settings.max_profiles
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
    return model, SideLayout(quads, a, u, n, t, present)


def _model_passes(lin: np.ndarray, sides: SideLayout, model: SideModel,
                  settings: EdgeFitSettings, cells: BorderCells, *, passes: int,
                  fit_order: np.ndarray, lens: Lens | None = None,
                  start_blur: np.ndarray | None = None, light: np.ndarray | None = None,
                  tone_probe: Callable[[ProbeFit], None] | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Blurred-step model fits (see :mod:`~artcal_ros.core.detect.step_model`); updates ``model``.

    Samples inside the border stay ``settings.margin_px`` inside both neighbouring sides (near
    an acute corner a cut straight inward would leave the marker through its neighbour).

    Args:
        lin: (H, W) float32 linear intensity image.
        sides: where the profiles lie (its quads are the fallback corners).
        model: the side model to refine (its coefficients are the start).
        settings, cells: as :func:`refine_quads` was given them.
        passes: model fits, each re-centred on the previous one.
        fit_order: (S,) int, per side: the parabola term free (3) or held at its current
            value (2: a straight line, or a lens-given bend).
        lens: optional lens (places the code cells along each side).
        start_blur: (S,) the blur the fit starts from (an earlier pass's), pixels; without,
            the frame's blur from a pilot fit of every 8th side.
        light: (S,) the light's slope along each side from an earlier pass
            (:func:`~.light.light_slopes`): the sides are fitted once, in that light;
            without, fitted, and the sides the light changes along fitted again in it.
        tone_probe: see :func:`refine_quads`.

    Returns:
        (S,) the fitted blur, pixels, and (S,) the light's slopes.
    """
    a, u, n, t, present = sides.a, sides.u, sides.n, sides.t, sides.present
    bits, quiet_modules = settings.bits, settings.quiet_modules
    inner_same, outer_same = cells.inner_same, cells.outer_same
    S = t.shape[0]
    M = S // 4
    blur = np.full(S, 0.8)  # along the side, for the code cells
    fit_blur = start_blur
    for _ in range(max(passes, 1)):
        corners, _ = intersect_sides(model, a, u, n, M)
        bad = ~np.isfinite(corners).all(axis=(1, 2))
        corners[bad] = sides.quads[bad]
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
            reach = np.clip((quiet_modules + settings.beyond_modules) * m_med - 1.2, 1.5, 5.0)
            outer = np.where(known, np.maximum(reach, outer), outer)
        # samples: the pixels nearest a grid of points along and across each side (raw
        # values: interpolation would add its own, phase-dependent edge shifts)
        span = (-int(np.ceil(inner.max())), int(np.ceil(outer.max())))
        read, basis, sid, used = gather_samples(
            lin, a, u, n, t, present, model.coef, model.length, model.order >= 3, span, inner,
            outer, neighbour_lines(corners), settings.margin_px)
        px_c, py_c, t_c, s_c, values, _ = read
        pts_c = np.stack([px_c, py_c], axis=-1)    # (the border's width places the code)
        along, m_s = sample_geometry(corners, pts_c, t_c, sid, sides, base, m_px, bits, lens)
        # (a mixed board's known edge beyond the quiet zone: better by the sample's width)
        quiet_m = m_s if known is None else module_geometry_at(corners, pts_c, sid, n,
                                                               bits, lens)[1]
        if rows:
            far = far_cells(along, sid, np.asarray(inner_same, bool).reshape(S, rows, bits),
                            blur * (bits + 2) / model.length)
        else:
            far = np.zeros((len(sid), 1), dtype=np.float32)
        samples = StepSamples(
            s=s_c, side=sid, n_sides=S, basis=basis, far=far, module_px=m_s,
            fit_order=fit_order, normal=n,
            outer=None if known is None else known[sid].astype(np.float32),
            quiet_px=None if known is None else quiet_modules * quiet_m)
        fit = partial(fit_step_model, samples=samples, tol_px=_FIT_TOL_PX,
                      censor_at=settings.censor_at)

        if fit_blur is None:
            # the frame's blur from a few sides first: the others then start close to
            # theirs (blur hardly varies across a frame) and need fewer steps
            few = np.flatnonzero(used > 0)[::_PILOT_EVERY]
            pilot = fit(values, coef0=model.coef, blur0=np.full(S, 0.6),
                        iterations=_PILOT_STEPS, sides=few)[2]
            fit_blur = np.full(S, float(np.median(pilot[few])) if len(few) else 0.6)
        contrast = np.zeros(S)
        # the light along the sides: known from an earlier pass (one fit, in that light),
        # else from this fit's contrasts, and the sides it changes along fitted again
        scaled = values if light is None else in_light(values, basis[:, 1], sid, light)[0]
        first = coef, cov, fit_blur = fit(scaled, coef0=model.coef, blur0=fit_blur,
                                          iterations=_FIT_STEPS, contrast_out=contrast)
        if light is None:  # (no light field of clipped light)
            (coef, cov, fit_blur), scaled, light = fit_in_light(
                partial(fit, iterations=_FIT_STEPS), values, basis[:, 1], sid, first, contrast,
                a, u, model.length,
                (used >= 4) & (settings.censor_at is None) & settings.light_field)
        fit = partial(fit, scaled)
        if settings.censor_at is not None and rows:
            # (only sides that are clipped: a frame may be clipped away from the board)
            clipped = np.bincount(sid, weights=values >= settings.censor_at, minlength=S) >= 3
            coef, cov, fit_blur = _refit_lone_edges(fit, coef, cov, fit_blur, contrast,
                                                    np.asarray(inner_same, bool),
                                                    used * clipped)
        if tone_probe is not None:
            few = np.flatnonzero(used > 0)[::_PILOT_EVERY]
            if len(few):
                tone_probe(ProbeFit(samples, values, few, coef, fit_blur, settings.censor_at))
        blur = fit_blur
        model.coef = coef
        model.cov = cov
        model.count = used
    assert fit_blur is not None and light is not None  # passes >= 1
    return fit_blur, light


# sides with between these shares of the other colour behind their border show their
# blur and contrast (see _refit_lone_edges)
_HELD_BELOW, _HELD_ABOVE = 0.3, 0.6


def _refit_lone_edges(fit: Callable[..., tuple[np.ndarray, np.ndarray, np.ndarray]],
                      coef: np.ndarray, cov: np.ndarray, blur: np.ndarray,
                      contrast: np.ndarray, inner_same: np.ndarray, used: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Clipped sides fitted again with the blur and contrast the well-placed ones show.

    With the paper clipped a side sees only the unclipped tails of its transitions. One
    with code cells of both colours behind its border shows two (border and code edge,
    same blur and contrast), which pins both down; one with (almost) a single colour
    behind cannot. Every clipped side is fitted again with the blur held at the median of
    the frame's two-transition sides (one focus) and the contrast at its marker's (one
    paper, one light; the frame's when the marker has none): only position and dark
    level stay free, so a marker's four sides are placed alike.

    Args:
        fit: the pass's fit (``fit(coef0=, **kw)``, see :func:`_model_passes`).
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


@dataclass(frozen=True)
class ProbeFit:
    """A pass's final step-model fit, kept so a tone probe can re-fit some of its sides.

    Attributes:
        samples: the fit's samples (N of them).
        values: (N,) the samples' linear values.
        sides: (F,) int, the sides a probe may re-fit (every 8th fitted side).
        coef, blur: (S, 3), (S,) the fit, pixels.
        censor_at: the fit's saturation level (None: nothing censored).
    """

    samples: StepSamples
    values: np.ndarray
    sides: np.ndarray
    coef: np.ndarray
    blur: np.ndarray
    censor_at: float | None = None

    def subset(self, sides: np.ndarray, copies: int = 1
               ) -> tuple[Callable[..., None], np.ndarray]:
        """``fit_values(values, **kw)`` on ``copies`` copies of only ``sides``' samples
        (:meth:`StepSamples.subset`; ``values``, ``coef0``, ``blur0`` and ``cost_out``
        copy-major), and those samples' values (one copy).

        A probe of several curves is then one call of the compiled fit, and the re-fits
        touch none of the frame's other samples.
        """
        sub, keep = self.samples.subset(sides, copies)

        def fit_values(values: np.ndarray, **kw: Any) -> None:
            fit_step_model(values, sub, iterations=_PROBE_STEPS, tol_px=_FIT_TOL_PX,
                           censor_at=self.censor_at, **kw)

        return fit_values, self.values[keep]
