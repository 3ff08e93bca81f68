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
together by damped Gauss-Newton.
"""

from __future__ import annotations

import warnings

import numpy as np

_INV_SQRT2 = float(1.0 / np.sqrt(2.0))  # Python floats keep float32 arrays float32
_INV_SQRT2PI = float(1.0 / np.sqrt(2.0 * np.pi))


def norm_cdf_pdf(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Standard normal CDF and density of z, sharing one exponential.

    The CDF uses Abramowitz & Stegun 7.1.26 for erf (absolute error < 1.5e-7).
    The dtype of z is kept (float32 halves the time of the model fit); the work
    is done in place to keep temporaries few.
    """
    z = np.asarray(z)
    a = np.abs(z)
    a *= _INV_SQRT2
    e = a * a
    np.negative(e, out=e)
    np.exp(e, out=e)
    t = a  # a is not needed any more
    t *= 0.3275911
    t += 1.0
    np.reciprocal(t, out=t)
    poly = t * 1.061405429
    for coef in (-1.453152027, 1.421413741, -0.284496736, 0.254829592):
        poly += coef
        poly *= t
    poly *= 0.5
    poly *= e  # Phi(-|z|)
    # Phi(z) = tail below 0, 1 - tail above (arithmetic select: np.where is slower)
    cdf = (z >= 0).astype(poly.dtype)
    cdf *= 1.0 - 2.0 * poly
    cdf += poly
    e *= _INV_SQRT2PI
    return cdf, e


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
        d: distance of the pixel center from the edge (positive on the bright side), pixels.
        sigma: Gaussian blur, pixels (broadcast with d).
        box_a, box_b: |nx|, |ny| (broadcast with d).

    Returns:
        value (0..1), d value / d d, d value / d log sigma (in d's float type).
    """
    a = np.maximum(box_a, 0.02)
    b = np.maximum(box_b, 0.02)
    inv_sigma = 1.0 / sigma
    # sums over the box's four corners of sgn * P2(z), sgn * P1(z) and sgn * z P1(z),
    # with P1 the antiderivative of Phi and P2 its antiderivative
    s2 = s1 = sz1 = None
    for shift, sgn in ((0.5 * (a + b), 1.0), (0.5 * (a - b), -1.0), (-0.5 * (a - b), -1.0),
                       (-0.5 * (a + b), 1.0)):
        z = d + shift
        z *= inv_sigma
        cdf, pdf = norm_cdf_pdf(z)
        p1 = z * cdf
        p1 += pdf
        p2 = z * z
        p2 += 1.0
        p2 *= cdf
        pdf *= z
        p2 += pdf
        p2 *= 0.5
        zp1 = z * p1
        if s2 is None:
            s2, s1, sz1 = p2, p1, zp1
        elif sgn > 0:
            s2 += p2
            s1 += p1
            sz1 += zp1
        else:
            s2 -= p2
            s1 -= p1
            sz1 -= zp1
    assert s2 is not None and s1 is not None and sz1 is not None
    inv = 1.0 / (a * b)
    sig2 = sigma * sigma * inv
    val = s2 * sig2
    # d/d log sigma of sigma^2 P2(c / sigma): 2 sigma^2 P2 - sigma c P1 = sigma^2 (2 P2 - z P1)
    s2 *= 2.0
    s2 -= sz1
    s2 *= sig2
    s1 *= sigma * inv
    return val, s1, s2


def fit_step_model(values: np.ndarray, s: np.ndarray, side: np.ndarray, n_sides: int,
                   basis: np.ndarray, coef0: np.ndarray, far: np.ndarray,
                   module_px: np.ndarray, fit_order: np.ndarray, normal: np.ndarray, *,
                   outer: np.ndarray | None = None, quiet_px: np.ndarray | None = None,
                   samples_per_px: float = 1.0, iterations: int = 4
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit the blurred-step model (module docstring) to every side.

    The N samples of all S sides come as flat arrays, each side's samples together
    (``side`` non-decreasing); only the samples to use are passed.

    Args:
        values: (N,) linear intensities of the samples.
        s: (N,) their offsets along their side's outward normal from its chord, pixels.
        side: (N,) int, the side (0 .. S-1) of each sample, non-decreasing.
        n_sides: S.
        basis: (N, 3) along-side polynomial basis (1, tau, tau^2 - 1/3) at each sample.
        coef0: (S, 3) starting edge polynomial (offset of the edge from the chord).
        far: (N, R) share of the other colour in code rows 1..R behind the border
            (see :func:`far_cells`).
        module_px: (N,) module width at each sample, pixels.
        fit_order: (S,) 3 where the parabola term is free, 2 where it is held.
        normal: (S, 2) each side's unit normal (sets the pixel's footprint across it).
        outer: optional (N,) share of the border's colour beyond the quiet zone at
            each sample (1 where the board puts a known edge there, 0 where not).
        quiet_px: (N,) the quiet zone's width at each sample, pixels (with ``outer``).
        samples_per_px: sample density along the normal (for the covariance: samples
            closer than a pixel are not independent).
        iterations: Gauss-Newton steps.

    Returns:
        coef (S, 3) edge polynomial, cov (S, 3, 3) its covariance, blur (S,) pixels
        (the Gaussian part, beyond the pixel's own footprint).
    """
    S = n_sides
    rows = far.shape[1]
    sid = np.asarray(side, dtype=np.intp)
    # the normal equations are formed per side in a padded (S, P) layout
    slot, P = side_slots(sid, S)
    per_side = np.bincount(sid, minlength=S)
    vals = np.asarray(values, dtype=np.float64)
    sc = np.asarray(s, dtype=np.float64)
    bas = np.asarray(basis, dtype=np.float64)
    farc = np.asarray(far, dtype=np.float32)
    modc = np.asarray(module_px, dtype=np.float32)
    outc = None if outer is None else np.asarray(outer, dtype=np.float32)
    quietc = None if quiet_px is None else np.asarray(quiet_px, dtype=np.float32)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # sides without samples: NaN
        rel = sc - np.einsum("np,np->n", bas, coef0[sid])
        A = side_median(vals, rel < -0.3, sid, slot, S, P)
        B = side_median(vals, rel > 0.3, sid, slot, S, P)
    p: np.ndarray = np.zeros((S, 6))  # edge polynomial (3), A, D, log w
    p[:, :3] = coef0
    p[:, 3] = np.nan_to_num(A)
    p[:, 4] = np.nan_to_num(B) - np.nan_to_num(A)
    p[:, 5] = np.log(0.6)
    box_a = np.abs(normal[:, 0])[sid].astype(np.float32)
    box_b = np.abs(normal[:, 1])[sid].astype(np.float32)
    box_var = (box_a * box_a + box_b * box_b) / 12.0
    lam: np.ndarray = np.full(S, 1e-3)
    quad = (fit_order >= 3).astype(np.float64)
    quad_c = quad[sid]
    bas_t = np.ascontiguousarray(bas.T)

    def evaluate(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # per-sample parameters, one contiguous column at a time (fast 1-D gathers)
        ps = [np.take(col, sid) for col in np.ascontiguousarray(p.T)]
        e = bas_t[0] * ps[0] + bas_t[1] * ps[1] + bas_t[2] * ps[2]
        # the model is evaluated in float32 (its noise is far below the image's);
        # the edge offset d is formed in float64 first so it keeps its precision
        w = np.maximum(np.exp(ps[5]), 0.03).astype(np.float32)
        d = (sc - e).astype(np.float32)
        F, g1, gw = pixel_esf(d, w, box_a, box_b)
        de = -g1
        # a Gaussian of the same second moment is close enough for the other edges
        w_eff = np.sqrt(w * w + box_var)
        shrink = (w * w) / (w_eff * w_eff)
        if outc is not None and quietc is not None:
            # the known edge beyond the quiet zone, back to the border's colour
            z = (d - quietc) / w_eff
            val, pdf = norm_cdf_pdf(z)
            F = F - outc * val
            de = de + outc * (pdf / w_eff)
            gw = gw + outc * (pdf * z * shrink)
        for r in range(rows):
            # the edge where code row r+1 begins, weighted by its change of colour
            c = farc[:, r] - (farc[:, r - 1] if r else 0.0)
            z = -(d + (r + 1) * modc) / w_eff
            val, pdf = norm_cdf_pdf(z)
            F = F + c * val
            de = de + c * (pdf / w_eff)
            gw = gw - c * (pdf * z * shrink)
        D = ps[4].astype(np.float32)
        res = vals - (ps[3] + D * F)
        de = D * de
        jac = np.empty((len(sid), 6), dtype=np.float32)
        jac[:, :3] = de[:, None] * bas
        jac[:, 2] *= quad_c
        jac[:, 3] = 1.0
        jac[:, 4] = F
        jac[:, 5] = D * gw  # d/d log w
        return res, jac

    flat_index = sid * P + slot

    def padded(jac: np.ndarray, res: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Jp = np.zeros((S * P, 6))
        Jp[flat_index] = jac
        rp = np.zeros(S * P)
        rp[flat_index] = res
        return Jp.reshape(S, P, 6), rp.reshape(S, P)

    def side_cost(res: np.ndarray) -> np.ndarray:
        return np.bincount(sid, weights=res * res, minlength=S)

    res, jac = evaluate(p)
    cost = side_cost(res)
    pad = np.zeros((S, 6, 6))
    pad[:, 2, 2] = 1.0 - quad
    for _ in range(iterations):
        Jf, rf = padded(jac, res)
        N = np.matmul(Jf.transpose(0, 2, 1), Jf) + pad
        g = np.matmul(Jf.transpose(0, 2, 1), rf[..., None])[..., 0]
        diag = np.einsum("sii->si", N)
        Nd = N + (lam[:, None] * (diag + 1e-9))[:, :, None] * np.eye(6)
        with np.errstate(all="ignore"):
            step = np.linalg.solve(Nd, g[..., None])[..., 0]
        step = np.nan_to_num(step)
        step[:, :2] = np.clip(step[:, :2], -1.0, 1.0)
        step[:, 5] = np.clip(step[:, 5], -0.5, 0.5)
        trial = p + step
        res_t, jac_t = evaluate(trial)
        cost_t = side_cost(res_t)
        better = cost_t < cost
        p = np.where(better[:, None], trial, p)
        bs = better[sid]
        res = np.where(bs, res_t, res)
        jac = np.where(bs[:, None], jac_t, jac)
        cost = np.where(better, cost_t, cost)
        lam = np.where(better, lam * 0.3, lam * 10.0)
    Jf, _ = padded(jac, res)
    N = np.matmul(Jf.transpose(0, 2, 1), Jf) + pad + 1e-12 * np.eye(6)
    n_samples = per_side.astype(np.float64)
    var = cost / np.maximum(n_samples - 6, 1.0)
    with np.errstate(all="ignore"):
        cov = np.linalg.inv(N)[:, :3, :3] * (var * max(samples_per_px, 1.0))[:, None, None]
    cov = np.nan_to_num(cov)
    cov[fit_order < 3, 2, :] = 0.0
    cov[fit_order < 3, :, 2] = 0.0
    return p[:, :3], cov, np.exp(p[:, 5])


def far_cells(along: np.ndarray, same: np.ndarray, blur_modules: np.ndarray) -> np.ndarray:
    """(N, ...) share of the other colour in one code row behind the border, blurred along it.

    Gaussian blur is separable, so behind a straight border the code cells'
    contribution at along-side position x is the sum over cells of the other
    colour of ``Phi((x - x0) / w) - Phi((x - x1) / w)`` (the ``c`` of the
    module docstring's model).

    Args:
        along: (N, ...) position of each sample along its side, modules (0 .. bits + 2).
        same: (N, bits) bool, per sample: the row's code cells (in side order)
            that share the border's colour.
        blur_modules: (N, ...) blur of each sample's side, in modules along the side
            (broadcast with ``along``).
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


def side_slots(side: np.ndarray, n_sides: int) -> tuple[np.ndarray, int]:
    """Position of every sample within its side, and the most samples of any side.

    Args:
        side: (N,) int, non-decreasing side index of each sample.
        n_sides: S.
    """
    count = np.bincount(side, minlength=n_sides)
    first = np.concatenate([[0], np.cumsum(count)[:-1]])
    return np.arange(len(side)) - first[side], max(int(count.max(initial=0)), 1)


def side_median(x: np.ndarray, use: np.ndarray, sid: np.ndarray, slot: np.ndarray,
                S: int, P: int) -> np.ndarray:
    """(S,) median of the samples x (N,) of each side where ``use`` (N,); NaN for none.

    ``sid``, ``slot`` and ``P`` as from :func:`side_slots`.

    Like ``np.nanmedian`` of a padded (S, P) layout (the mean of the two middle
    values for an even count), without its masked-array overhead.
    """
    pad = np.full((S, P), np.inf)
    pad[sid[use], slot[use]] = x[use]
    pad.sort(axis=1)
    count = np.bincount(sid[use], minlength=S)
    lo = np.take_along_axis(pad, np.maximum((count - 1) // 2, 0)[:, None], 1)[:, 0]
    hi = np.take_along_axis(pad, np.minimum(count // 2, P - 1)[:, None], 1)[:, 0]
    return np.where(count > 0, 0.5 * (lo + hi), np.nan)
