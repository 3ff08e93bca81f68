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
is separable). All sides are solved together by damped Gauss-Newton.
"""

from __future__ import annotations

import warnings

import numpy as np

_SQRT2 = np.sqrt(2.0)
_INV_SQRT2PI = 1.0 / np.sqrt(2.0 * np.pi)


def norm_cdf_pdf(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard normal CDF and density of z, sharing one exponential.

    The CDF uses Abramowitz & Stegun 7.1.26 for erf (absolute error < 1.5e-7).
    """
    a = np.abs(z) * (1.0 / _SQRT2)
    e = np.exp(-a * a)
    t = 1.0 / (1.0 + 0.3275911 * a)
    poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741
                                                      + t * (-1.453152027 + t * 1.061405429))))
    half_tail = 0.5 * poly * e  # Phi(-|z|)
    cdf = np.where(z >= 0, 1.0 - half_tail, half_tail)
    return cdf, _INV_SQRT2PI * e


def phi_cdf(z: np.ndarray) -> np.ndarray:
    """Standard normal CDF."""
    return norm_cdf_pdf(z)[0]


def pixel_esf(d: np.ndarray, sigma: np.ndarray, box_a: np.ndarray, box_b: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Edge-spread function of a square pixel with Gaussian blur, and its derivatives.

    A pixel integrates over its square; across an edge whose normal is (nx, ny)
    that is a box of width |nx| convolved with one of width |ny|. With a Gaussian
    blur of ``sigma`` the step's image at signed distance ``d`` from the edge is
    closed-form in the second antiderivative of the normal CDF.

    Args:
        d: distance of the pixel centre from the edge (positive on the bright side), pixels.
        sigma: Gaussian blur, pixels (broadcast with d).
        box_a, box_b: |nx|, |ny| (broadcast with d).

    Returns:
        value (0..1), d value / d d, d value / d log sigma.
    """
    a = np.maximum(box_a, 0.02)
    b = np.maximum(box_b, 0.02)
    corners = ((0.5 * (a + b), 1.0), (0.5 * (a - b), -1.0), (-0.5 * (a - b), -1.0),
               (-0.5 * (a + b), 1.0))
    val = np.zeros(np.broadcast(d, sigma, a, b).shape)
    dval = np.zeros_like(val)
    dsig = np.zeros_like(val)
    for shift, sgn in corners:
        c = d + shift
        z = c / sigma
        cdf, pdf = norm_cdf_pdf(z)
        p1 = z * cdf + pdf  # antiderivative of Phi
        p2 = 0.5 * ((z * z + 1.0) * cdf + z * pdf)  # and its antiderivative
        val += sgn * sigma * sigma * p2
        dval += sgn * sigma * p1
        dsig += sgn * (2.0 * sigma * sigma * p2 - sigma * c * p1)
    inv = 1.0 / (a * b)
    return val * inv, dval * inv, dsig * inv


def fit_step_model(values: np.ndarray, s: np.ndarray, mask: np.ndarray, basis: np.ndarray,
                   coef0: np.ndarray, far: np.ndarray, module_px: np.ndarray,
                   fit_order: np.ndarray, normal: np.ndarray, *, samples_per_px: float = 1.0,
                   iterations: int = 4
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fit the blurred-step model (module docstring) to every side.

    Args:
        values: (S, K, J) linear intensities of the samples of each side.
        s: (S, K, J) their offsets along the side's outward normal from its chord, pixels.
        mask: (S, K, J) bool, samples to use.
        basis: (S, K, J, 3) along-side polynomial basis (1, tau, tau^2 - 1/3) at each sample.
        coef0: (S, 3) starting edge polynomial (offset of the edge from the chord).
        far: (S, K, J, R) share of the other colour in code rows 1..R behind the border.
        module_px: (S, K, J) module width at each sample, pixels.
        fit_order: (S,) 3 where the parabola term is free, 2 where it is held.
        normal: (S, 2) each side's unit normal (sets the pixel's footprint across it).
        samples_per_px: sample density along the normal (for the covariance: samples
            closer than a pixel are not independent).
        iterations: Gauss-Newton steps.

    Returns:
        coef (S, 3) edge polynomial, cov (S, 3, 3) its covariance, blur (S,) pixels
        (the Gaussian part, beyond the pixel's own footprint),
        residual rms (S,) linear units, profiles used (S,).
    """
    S = values.shape[0]
    m = mask.astype(np.float64)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # sides without samples: NaN
        rel = s - np.einsum("skjp,sp->skj", basis, coef0)
        A = np.nanmedian(np.where(mask & (rel < -0.3), values, np.nan).reshape(S, -1), axis=1)
        B = np.nanmedian(np.where(mask & (rel > 0.3), values, np.nan).reshape(S, -1), axis=1)
    p = np.zeros((S, 6))  # edge polynomial (3), A, D, log w
    p[:, :3] = coef0
    p[:, 3] = np.nan_to_num(A)
    p[:, 4] = np.nan_to_num(B) - np.nan_to_num(A)
    p[:, 5] = np.log(0.6)
    box_a = np.abs(normal[:, 0])[:, None, None]
    box_b = np.abs(normal[:, 1])[:, None, None]
    lam = np.full(S, 1e-3)
    quad = (fit_order >= 3).astype(np.float64)
    rows = far.shape[3]

    def evaluate(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        e = np.einsum("skjp,sp->skj", basis, p[:, :3])
        w = np.maximum(np.exp(p[:, 5]), 0.03)[:, None, None]
        F, g1, gw = pixel_esf(s - e, w, box_a, box_b)
        de = -g1
        for r in range(rows):
            # the edge where code row r+1 begins, weighted by its change of colour
            c = far[..., r] - (far[..., r - 1] if r else 0.0)
            # a Gaussian of the same second moment is close enough for this correction
            w_eff = np.sqrt(w * w + (box_a * box_a + box_b * box_b) / 12.0)
            z = -(s - e + (r + 1) * module_px) / w_eff
            val, pdf = norm_cdf_pdf(z)
            dv = pdf / w_eff
            dw = -pdf * z * (w * w) / (w_eff * w_eff)
            F = F + c * val
            de = de + c * dv
            gw = gw + c * dw
        D = p[:, 4, None, None]
        res = (values - (p[:, 3, None, None] + D * F)) * m
        de = D * de * m
        jac = np.empty((*values.shape, 6))
        jac[..., 0] = de * basis[..., 0]
        jac[..., 1] = de * basis[..., 1]
        jac[..., 2] = de * basis[..., 2] * quad[:, None, None]
        jac[..., 3] = m
        jac[..., 4] = F * m
        jac[..., 5] = D * gw * m  # d/d log w
        return res, jac

    res, jac = evaluate(p)
    cost = (res * res).sum(axis=(1, 2))
    pad = np.zeros((S, 6, 6))
    pad[:, 2, 2] = 1.0 - quad
    for _ in range(iterations):
        Jf = jac.reshape(S, -1, 6)
        N = np.matmul(Jf.transpose(0, 2, 1), Jf) + pad
        g = np.matmul(Jf.transpose(0, 2, 1), res.reshape(S, -1, 1))[..., 0]
        diag = np.einsum("sii->si", N)
        Nd = N + (lam[:, None] * (diag + 1e-9))[:, :, None] * np.eye(6)
        with np.errstate(all="ignore"):
            step = np.linalg.solve(Nd, g[..., None])[..., 0]
        step = np.nan_to_num(step)
        step[:, :2] = np.clip(step[:, :2], -1.0, 1.0)
        step[:, 5] = np.clip(step[:, 5], -0.5, 0.5)
        trial = p + step
        res_t, jac_t = evaluate(trial)
        cost_t = (res_t * res_t).sum(axis=(1, 2))
        better = cost_t < cost
        p = np.where(better[:, None], trial, p)
        res = np.where(better[:, None, None], res_t, res)
        jac = np.where(better[:, None, None, None], jac_t, jac)
        cost = np.where(better, cost_t, cost)
        lam = np.where(better, lam * 0.3, lam * 10.0)
    Jf = jac.reshape(S, -1, 6)
    N = np.matmul(Jf.transpose(0, 2, 1), Jf) + pad + 1e-12 * np.eye(6)
    n_samples = m.sum(axis=(1, 2))
    var = cost / np.maximum(n_samples - 6, 1.0)
    with np.errstate(all="ignore"):
        cov = np.linalg.inv(N)[:, :3, :3] * (var * max(samples_per_px, 1.0))[:, None, None]
    cov = np.nan_to_num(cov)
    cov[fit_order < 3, 2, :] = 0.0
    cov[fit_order < 3, :, 2] = 0.0
    return (p[:, :3], cov, np.exp(p[:, 5]), np.sqrt(var),
            mask.any(axis=2).sum(axis=1).astype(np.intp))
