"""Edge-model fit: a marker side's border edge located by fitting a blurred-step model.

A small marker's border band is only a few pixels wide, so under blur the far
edge of the band (where a white code cell starts) leaks into any window that
is wide enough to see the outer edge properly; thresholds and areas then drift
outward. Since the marker has been decoded, the printed pattern behind the
border is known. Each profile across the side is modelled in linear intensity
as

    I(s) = A + D * (Phi((s - e) / w) + c1 * Phi(-(s - e + m) / w)
                        + (c2 - c1) * Phi(-(s - e + 2 m) / w))

with ``e`` the edge's offset (a line or parabola along the side), ``w`` the
blur (one per side: optics and pixel integration together), ``A`` the border's
level and ``A + D`` the quiet zone's, ``m`` the module width at that point (from
the quad's homography) and ``c1``, ``c2`` the share of the other colour in the
first and second code rows behind the border at that point (known from the
decoded id; blurred along the side, which is exact for a Gaussian blur since it
is separable). Where the board puts a known edge just beyond the quiet zone
(the neighbouring tile of a mixed board), a term ``- c_out * Phi((s - e - q) / w)``
models it too, ``q`` being the quiet zone's width there. All sides are solved
one by one by damped Gauss-Newton (a compiled kernel).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from artcal_ros.core.detect.linalg import median_small, solve
from artcal_ros.core.detect.workers import run_all, split_even

# A&S 7.1.26 coefficients of erfc (absolute error < 1.5e-7)
_P = 0.3275911
_A1, _A2, _A3, _A4, _A5 = 0.254829592, -0.284496736, 1.421413741, -1.453152027, 1.061405429
_INV_SQRT2 = 1.0 / math.sqrt(2.0)
_INV_SQRT2PI = 1.0 / math.sqrt(2.0 * math.pi)


# inlined by numba: LLVM alone leaves the per-sample calls in place, in the fit's inner loop
@njit(cache=True, error_model="numpy", inline="always")
def norm_cdf_pdf(z: float) -> tuple[float, float]:
    """Standard normal CDF and density of a scalar z, sharing one exponential.

    The CDF uses Abramowitz & Stegun 7.1.26 for erf (absolute error < 1.5e-7).
    """
    a = abs(z) * _INV_SQRT2
    if a > 6.5:
        # beyond 9.2 sigma both tails are below 1e-19: no exponential needed
        return (1.0 if z >= 0.0 else 0.0), 0.0
    e = math.exp(-a * a)
    t = 1.0 / (1.0 + _P * a)
    tail = 0.5 * e * t * (_A1 + t * (_A2 + t * (_A3 + t * (_A4 + t * _A5))))  # Phi(-|z|)
    cdf = 1.0 - tail if z >= 0.0 else tail
    return cdf, e * _INV_SQRT2PI


# inlined by numba: LLVM alone leaves the per-sample calls in place, in the fit's inner loop
@njit(cache=True, error_model="numpy", inline="always")
def pixel_esf(d: float, sigma: float, box_a: float, box_b: float
              ) -> tuple[float, float, float]:
    """Edge-spread function of a square pixel with Gaussian blur, and its derivatives.

    A pixel integrates over its square; across an edge whose normal is (nx, ny)
    that is a box of width |nx| convolved with one of width |ny|. With a Gaussian
    blur of ``sigma`` the step's image at signed distance ``d`` from the edge is
    closed-form in the second antiderivative of the normal CDF.

    Args:
        d: distance of the pixel center from the edge (positive on the bright side), pixels.
        sigma: Gaussian blur, pixels.
        box_a, box_b: |nx|, |ny| of the edge's normal.

    Returns:
        value (0..1), d value / d d, d value / d log sigma.
    """
    a = max(box_a, 0.02)
    b = max(box_b, 0.02)
    inv_sigma = 1.0 / sigma
    # a pixel wholly on one side of the blurred edge (most of a sharp edge's band)
    if (d - 0.5 * (a + b)) * inv_sigma > 9.2:
        return 1.0, 0.0, 0.0
    if (d + 0.5 * (a + b)) * inv_sigma < -9.2:
        return 0.0, 0.0, 0.0
    # sums over the box's four corners of sgn * P2(z), sgn * P1(z) and sgn * z P1(z),
    # with P1 the antiderivative of Phi and P2 its antiderivative
    s2 = 0.0
    s1 = 0.0
    sz1 = 0.0
    for k in range(4):
        if k == 0:
            shift, sgn = 0.5 * (a + b), 1.0
        elif k == 1:
            shift, sgn = 0.5 * (a - b), -1.0
        elif k == 2:
            shift, sgn = -0.5 * (a - b), -1.0
        else:
            shift, sgn = -0.5 * (a + b), 1.0
        z = (d + shift) * inv_sigma
        cdf, pdf = norm_cdf_pdf(z)
        p1 = z * cdf + pdf
        p2 = 0.5 * ((z * z + 1.0) * cdf + z * pdf)
        s2 += sgn * p2
        s1 += sgn * p1
        sz1 += sgn * z * p1
    sig2 = sigma * sigma / (a * b)
    # d/d log sigma of sigma^2 P2(c / sigma): 2 sigma^2 P2 - sigma c P1 = sigma^2 (2 P2 - z P1)
    return s2 * sig2, s1 * sigma / (a * b), (2.0 * s2 - sz1) * sig2


@njit(cache=True, error_model="numpy")
def _levels(values: np.ndarray, s: np.ndarray, basis: np.ndarray, c: np.ndarray, lo: int,
            hi: int) -> tuple[float, float]:
    """Medians of values[lo:hi] more than 0.3 px inside and outside the edge c (3,).

    0 where there are none; the offset from the edge is ``s - basis . c``.
    """
    n = hi - lo
    buf = np.empty(n)   # those inside from the front, those outside from the back
    inside = outside = 0
    for i in range(lo, hi):
        rel = s[i] - (basis[i, 0] * c[0] + basis[i, 1] * c[1] + basis[i, 2] * c[2])
        if rel < -0.3:
            buf[inside] = values[i]
            inside += 1
        elif rel > 0.3:
            outside += 1
            buf[n - outside] = values[i]
    a = median_small(buf, inside) if inside else np.nan
    b = median_small(buf[n - outside:], outside) if outside else np.nan
    return (0.0 if np.isnan(a) else a), (0.0 if np.isnan(b) else b)


@njit(cache=True, error_model="numpy")
def _normal_equations(p: np.ndarray, lo: int, hi: int, values: np.ndarray, s: np.ndarray,
                      basis: np.ndarray, far: np.ndarray, module_px: np.ndarray,
                      outer: np.ndarray, quiet_px: np.ndarray, box_a: float, box_b: float,
                      quad: float, N: np.ndarray, g: np.ndarray, sat: float
                      ) -> tuple[float, float]:
    """Gauss-Newton normal equations of one side's samples lo..hi at parameters p (6,).

    Fills N (6, 6) = J^T J and g (6,) = J^T r; returns the cost r^T r and its part
    from the samples across the edge's transition (within 0.7 px plus two blurs of
    it, and less than half a module: where the tone curve shapes the profile). The
    model is the module docstring's; p = (edge polynomial (3), A, D, log w). A sample
    at or above ``sat`` (a saturated pixel) is censored: it only says the light there
    reached saturation, so it counts only where the model predicts less.
    """
    rows = far.shape[1]
    has_outer = outer.shape[0] > 0
    w = max(math.exp(p[5]), 0.03)
    # a Gaussian of the same second moment is close enough for the other edges
    box_var = (box_a * box_a + box_b * box_b) / 12.0
    w_eff = math.sqrt(w * w + box_var)
    shrink = (w * w) / (w_eff * w_eff)
    D = p[4]
    band = 0.7 + 2.0 * w
    # the sums are kept in scalars (registers); an array would be re-read every sample
    n00 = n10 = n11 = n20 = n21 = n22 = n30 = n31 = n32 = n33 = n40 = 0.0
    n41 = n42 = n43 = n44 = n50 = n51 = n52 = n53 = n54 = n55 = 0.0
    r0 = r1 = r2 = r3 = r4 = r5 = cost = band_cost = 0.0
    for i in range(lo, hi):
        d = s[i] - (basis[i, 0] * p[0] + basis[i, 1] * p[1] + basis[i, 2] * p[2])
        F, g1, gw = pixel_esf(d, w, box_a, box_b)
        de = -g1
        if has_outer:
            # the known edge beyond the quiet zone, back to the border's colour
            z = (d - quiet_px[i]) / w_eff
            val, pdf = norm_cdf_pdf(z)
            F -= outer[i] * val
            de += outer[i] * (pdf / w_eff)
            gw += outer[i] * (pdf * z * shrink)
        prev = 0.0
        for r in range(rows):
            # the edge where code row r+1 begins, weighted by its change of colour
            c = far[i, r] - prev
            prev = far[i, r]
            z = -(d + (r + 1) * module_px[i]) / w_eff
            val, pdf = norm_cdf_pdf(z)
            F += c * val
            de += c * (pdf / w_eff)
            gw -= c * (pdf * z * shrink)
        res = values[i] - (p[3] + D * F)
        if values[i] >= sat and res <= 0.0:
            continue
        cost += res * res
        if abs(d) < band and abs(d) < 0.5 * module_px[i]:
            band_cost += res * res
        if de == 0.0 and gw == 0.0:
            # every edge's tail is flat here (most of a sharp edge's band): only the
            # levels A and D see this sample
            r3 += res
            r4 += F * res
            n33 += 1.0
            n43 += F
            n44 += F * F
            continue
        de *= D
        # the Jacobian row: d/d (c0, c1, c2, A, D, log w)
        j0 = de * basis[i, 0]
        j1 = de * basis[i, 1]
        j2 = de * basis[i, 2] * quad
        j3 = 1.0
        j4 = F
        j5 = D * gw
        r0 += j0 * res
        r1 += j1 * res
        r2 += j2 * res
        r3 += j3 * res
        r4 += j4 * res
        r5 += j5 * res
        n00 += j0 * j0
        n10 += j1 * j0
        n11 += j1 * j1
        n20 += j2 * j0
        n21 += j2 * j1
        n22 += j2 * j2
        n30 += j3 * j0
        n31 += j3 * j1
        n32 += j3 * j2
        n33 += j3 * j3
        n40 += j4 * j0
        n41 += j4 * j1
        n42 += j4 * j2
        n43 += j4 * j3
        n44 += j4 * j4
        n50 += j5 * j0
        n51 += j5 * j1
        n52 += j5 * j2
        n53 += j5 * j3
        n54 += j5 * j4
        n55 += j5 * j5
    lower = (n00, n10, n11, n20, n21, n22, n30, n31, n32, n33, n40, n41, n42, n43, n44,
             n50, n51, n52, n53, n54, n55)
    k = 0
    for a in range(6):
        for b in range(a + 1):
            N[a, b] = N[b, a] = lower[k]
            k += 1
    g[0], g[1], g[2], g[3], g[4], g[5] = r0, r1, r2, r3, r4, r5
    return cost, band_cost


@njit(cache=True, error_model="numpy", nogil=True)
def _fit_sides(values: np.ndarray, s: np.ndarray, starts: np.ndarray, basis: np.ndarray,
               coef0: np.ndarray, far: np.ndarray, module_px: np.ndarray,
               fit_order: np.ndarray, normal: np.ndarray, outer: np.ndarray,
               quiet_px: np.ndarray, cov_scale: float, iterations: int, blur0: np.ndarray,
               tol_px: float, sat: float, hold_w: np.ndarray, hold_D: np.ndarray,
               which: np.ndarray, coef: np.ndarray, cov: np.ndarray, blur: np.ndarray,
               cost_out: np.ndarray, contrast: np.ndarray) -> None:
    """Damped Gauss-Newton fit of the sides ``which``; see :func:`fit_step_model`.

    Writes rows ``which`` of coef (S, 3), cov (S, 3, 3), blur (S,), cost_out (S,) and
    contrast (S,) (and nothing else, so threads can share them). A side with
    ``hold_w[k] > 0`` keeps that blur, one with a finite ``hold_D[k]`` that contrast.
    """
    for k in which:
        lo, hi = starts[k], starts[k + 1]
        quad = 1.0 if fit_order[k] >= 3 else 0.0
        box_a, box_b = abs(normal[k, 0]), abs(normal[k, 1])
        A, B = _levels(values, s, basis, coef0[k], lo, hi)
        p = np.empty(6)
        for j in range(3):
            p[j] = coef0[k, j]
        p[3] = A
        p[4] = B - A
        p[5] = math.log(max(blur0[k], 0.03))
        free_w = hold_w[k] <= 0.0
        free_D = not np.isfinite(hold_D[k])
        if not free_w:
            p[5] = math.log(max(hold_w[k], 0.03))
        if not free_D:
            p[4] = hold_D[k]
        N = np.empty((6, 6))
        g = np.empty(6)
        Nt = np.empty((6, 6))
        gt = np.empty(6)
        cost, band_cost = _normal_equations(p, lo, hi, values, s, basis, far, module_px,
                                            outer, quiet_px, box_a, box_b, quad, N, g, sat)
        lam = 1e-3
        Nd = np.empty((6, 6))
        rhs = np.empty((6, 1))
        trial = np.empty(6)
        unit = np.zeros((6, 3))
        for j in range(3):
            unit[j, j] = 1.0
        for _ in range(iterations):
            # (element loops, not array expressions: each of those is a kernel of its
            # own for numba to compile)
            for a in range(6):
                for b in range(6):
                    Nd[a, b] = N[a, b]
            Nd[2, 2] += 1.0 - quad  # a held parabola term: an identity row
            for j in range(6):
                Nd[j, j] += lam * (Nd[j, j] + 1e-9)
                rhs[j, 0] = g[j]
            step = solve(Nd, rhs)
            moved = 0.0
            for j in range(6):
                st = step[j, 0] if np.isfinite(step[j, 0]) else 0.0
                if j < 2:
                    st = min(max(st, -1.0), 1.0)
                elif j == 5:
                    st = min(max(st, -0.5), 0.5) if free_w else 0.0
                elif j == 4 and not free_D:
                    st = 0.0
                if j < 3:
                    moved += abs(st)
                trial[j] = p[j] + st
            # below 0.03 px the model does not see the blur any more
            trial[5] = max(trial[5], math.log(0.03))
            if moved < tol_px and abs(trial[5] - p[5]) < 0.02:
                break
            cost_t, band_t = _normal_equations(trial, lo, hi, values, s, basis, far,
                                               module_px, outer, quiet_px, box_a, box_b,
                                               quad, Nt, gt, sat)
            if cost_t < cost:
                for a in range(6):
                    p[a] = trial[a]
                    g[a] = gt[a]
                    for b in range(6):
                        N[a, b] = Nt[a, b]
                cost, band_cost = cost_t, band_t
                lam *= 0.3
            else:
                lam *= 10.0
        for a in range(6):
            for b in range(6):
                Nd[a, b] = N[a, b]
        Nd[2, 2] += 1.0 - quad
        for j in range(6):
            Nd[j, j] += 1e-12
        inv = solve(Nd, unit)
        var = cost / max(hi - lo - 6.0, 1.0) * cov_scale
        for a in range(3):
            for b in range(3):
                v = inv[a, b] * var
                cov[k, a, b] = v if np.isfinite(v) else 0.0
                if quad == 0.0 and (a == 2 or b == 2):
                    cov[k, a, b] = 0.0
        for j in range(3):
            coef[k, j] = p[j]
        blur[k] = math.exp(p[5])
        contrast[k] = p[4]
        cost_out[k] = band_cost / max(p[4] * p[4], 1e-12)


@dataclass(frozen=True)
class StepSamples:
    """The samples of S sides the step model is fitted to, flat and each side's together.

    Attributes:
        s: (N,) offset of each sample from its side's chord along the outward normal, pixels.
        side: (N,) int, the side (0 .. S-1) of each sample, non-decreasing.
        n_sides: S.
        basis: (N, 3) the edge polynomial's basis (1, tau, tau^2 - 1/3) at each sample.
        far: (N, R) share of the other colour in code rows 1..R behind the border
            (see :func:`~artcal_ros.core.detect.sides.far_cells`).
        module_px: (N,) module width at each sample, pixels.
        fit_order: (S,) int, 3 where the parabola term is free, 2 where it is held.
        normal: (S, 2) each side's unit normal (sets the pixel's footprint across it).
        outer: optional (N,) share of the border's colour beyond the quiet zone at each
            sample (1 where the board puts a known edge there, 0 where not).
        quiet_px: (N,) the quiet zone's width at each sample, pixels (with ``outer``).
    """

    s: np.ndarray
    side: np.ndarray
    n_sides: int
    basis: np.ndarray
    far: np.ndarray
    module_px: np.ndarray
    fit_order: np.ndarray
    normal: np.ndarray
    outer: np.ndarray | None = None
    quiet_px: np.ndarray | None = None

    def subset(self, sides: np.ndarray, copies: int = 1) -> tuple[StepSamples, np.ndarray]:
        """Only the F ``sides``' samples, ``copies`` times over, and the kept samples' indices
        (N',) into this set (one copy).

        The copies are one set of ``copies * F`` sides: copy c's side f is side ``c F + f``.
        """
        side = np.asarray(self.side)
        sides = np.asarray(sides)
        lo = np.searchsorted(side, sides)
        hi = np.searchsorted(side, sides, side="right")
        keep = np.concatenate([np.arange(a, b) for a, b in zip(lo, hi, strict=True)]
                              + [np.zeros(0, np.intp)])
        f = len(sides)
        local = np.repeat(np.arange(f), hi - lo)   # the kept samples' side, renumbered

        def per_sample(v: np.ndarray) -> np.ndarray:
            return np.concatenate([np.asarray(v)[keep]] * copies)

        def per_side(v: np.ndarray) -> np.ndarray:
            return np.concatenate([np.asarray(v)[sides]] * copies)

        sub = StepSamples(
            s=per_sample(self.s), side=np.concatenate([local + c * f for c in range(copies)]),
            n_sides=copies * f, basis=per_sample(self.basis), far=per_sample(self.far),
            module_px=per_sample(self.module_px), fit_order=per_side(self.fit_order),
            normal=per_side(self.normal),
            outer=None if self.outer is None else per_sample(self.outer),
            quiet_px=None if self.quiet_px is None else per_sample(self.quiet_px))
        return sub, keep


def fit_step_model(values: np.ndarray, samples: StepSamples, coef0: np.ndarray, *,
                   samples_per_px: float = 1.0, iterations: int = 4,
                   blur0: np.ndarray | None = None, tol_px: float = 0.0,
                   sides: np.ndarray | None = None, cost_out: np.ndarray | None = None,
                   censor_at: float | None = None, hold_blur: np.ndarray | None = None,
                   hold_contrast: np.ndarray | None = None,
                   contrast_out: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit the blurred-step model (module docstring) to every side, each on its own by
    damped Gauss-Newton (a compiled kernel).

    Args:
        values: (N,) linear intensities of the samples.
        samples: where the samples lie and what the board prints there.
        coef0: (S, 3) starting edge polynomial (offset of the edge from the chord), pixels.
        samples_per_px: sample density along the normal (for the covariance: samples
            closer than a pixel are not independent).
        iterations: most Gauss-Newton steps.
        blur0: (S,) the blur to start from, pixels (0.6 px without).
        tol_px: a side stops early once a step moves its edge by less than this (and
            its log blur by less than 0.02), pixels.
        sides: optional (F,) int, the sides to fit (the others keep ``coef0``, ``blur0``
            and a zero covariance).
        cost_out: optional (S,) filled with each fitted side's sum of squared residuals
            across the edge's transition (see :func:`_normal_equations`) over ``D ** 2``.
        censor_at: optional saturation level (linear): samples at or above it count only
            where the model predicts less light (over-exposed frames whose paper clips).
        hold_blur: optional (S,) blur to hold a side at, pixels (0: fitted).
        hold_contrast: optional (S,) contrast ``D`` to hold a side at (NaN: fitted).
        contrast_out: optional (S,) filled with each fitted side's contrast ``D``.

    Returns:
        coef (S, 3) edge polynomial, pixels; cov (S, 3, 3) its covariance, pixels^2; blur
        (S,) pixels (the Gaussian part, beyond the pixel's own footprint).
    """
    n_sides = samples.n_sides
    starts = np.searchsorted(np.asarray(samples.side),
                             np.arange(n_sides + 1)).astype(np.intp)
    f64 = np.float64
    none = np.zeros(0)
    which = np.arange(n_sides) if sides is None else np.ascontiguousarray(sides, np.intp)
    # sides not fitted keep their start
    coef = np.array(coef0, dtype=f64)
    cov = np.zeros((n_sides, 3, 3))
    blur = np.full(n_sides, 0.6) if blur0 is None else np.array(blur0, dtype=f64)
    # the one place the samples and options become the kernel's arrays and scalars
    args = (np.ascontiguousarray(values, f64), np.ascontiguousarray(samples.s, f64), starts,
            np.ascontiguousarray(samples.basis, f64), coef.copy(),
            np.ascontiguousarray(samples.far, f64),
            np.ascontiguousarray(samples.module_px, f64),
            np.ascontiguousarray(samples.fit_order, np.intp),
            np.ascontiguousarray(samples.normal, f64),
            none if samples.outer is None else np.ascontiguousarray(samples.outer, f64),
            none if samples.quiet_px is None else np.ascontiguousarray(samples.quiet_px, f64),
            max(samples_per_px, 1.0), int(iterations), blur.copy(), float(tol_px),
            1e30 if censor_at is None else float(censor_at),
            np.zeros(n_sides) if hold_blur is None else np.ascontiguousarray(hold_blur, f64),
            np.full(n_sides, np.nan) if hold_contrast is None
            else np.ascontiguousarray(hold_contrast, f64))
    # sides in runs of about equal sample counts, on the worker threads
    costs = np.zeros(n_sides) if cost_out is None else cost_out
    in_run = split_even(which, starts[which + 1] - starts[which])
    contrast = np.zeros(n_sides) if contrast_out is None else contrast_out
    run_all(lambda part: _fit_sides(*args, part, coef, cov, blur, costs, contrast), in_run)
    return coef, cov, blur
