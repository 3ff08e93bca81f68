"""Straight board edges under a lens: how a lens bends a side, and the lens from bent sides.

The board's edges are straight, so a lens model says exactly how each side's
image bends (:func:`lens_bend`), and the bends of many sides say what the lens
is (:func:`estimate_division`, the plumb-line method with a division model).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from artcal_ros.core.detect.lens import DivisionLens, Lens, LensPool, division_undistort
from artcal_ros.core.detect.sides import SideModel, side_frames

# the plausible division lenses (unit radius: the image's half diagonal): barrel distortion
# as strong as a 170-degree equidistant lens's (about -1.1, -0.25, -0.08), pincushion of at
# most lam +1.0. Camera lenses do not have pincushion that strong; the sides of noisy dark
# frames of a barrel lens can fit it, and a looser symmetric bound would let those through.
LAM_RANGE = (-2.0, 1.0)
MAX_HIGHER = 1.0  # |lam2|, |lam3|
# the largest share of the usable sides a plausible lens may leave beyond its fold
MAX_BEYOND_FOLD = 0.1
# a side's curvature (its parabola term, px) is trusted to no better than this: the
# division model only approximates a lens, and the step model's own error under heavy
# defocus bends short sides (a lower floor lets a clean frame's short outer sides weigh as
# much as long ones)
CURVATURE_FLOOR = 0.01
# a frame fitted alone (nothing pooled yet) has its priors this much weaker: against one
# frame's sides they would shrink the lens toward no distortion and bend the sides too little
# (corners outward under barrel distortion); a pool's many frames outweigh them anyway
LONE_FRAME_PRIOR = 0.01


def lens_bend(lens: Lens, a: np.ndarray, u: np.ndarray, n: np.ndarray,
              length: np.ndarray) -> np.ndarray:
    """(S,) parabola coefficient of the image of a straight edge between each side's ends.

    The chord's midpoint is mapped to straightened pixels, where the edge is
    straight, and back; its offset along the normal is the sag, and the
    parabola term (tau^2 - 1/3) of the fitted offset is minus the sag.

    Args:
        lens: the lens model.
        a, u, n: (S, 2) side frames (:func:`~artcal_ros.core.detect.sides.side_frames`).
        length: (S,) side lengths, pixels.
    """
    p0 = a
    p1 = a + length[:, None] * u
    und = lens.undistort(np.concatenate([p0, p1]))
    mid_u = 0.5 * (und[: len(a)] + und[len(a):])
    mid_d = lens.distort(mid_u)
    sag = np.einsum("sd,sd->s", mid_d - 0.5 * (p0 + p1), n)
    if isinstance(lens, DivisionLens):
        # beyond the model's fold there is no straightened edge to bend by
        sag[~lens.one_to_one(np.concatenate([p0, p1])).reshape(2, -1).all(axis=0)] = 0.0
    return -np.nan_to_num(sag)


def _side_curvature(lens: DivisionLens, pts: np.ndarray, quads: np.ndarray,
                    valid: np.ndarray) -> np.ndarray:
    """(S,) parabola coefficient of every side's edge points after straightening by ``lens``.

    One unweighted least-squares parabola per side (what SideModel.fit's first
    step does), without the robust rescaling and covariance that are not used here.

    Args:
        lens: the division lens to straighten with.
        pts: (S, K, 2) edge points, pixels.
        quads: (M, 4, 2) the quads the sides belong to, pixels.
        valid: (S, K) bool, the points to use.
    """
    M = len(quads)
    center = np.asarray(lens.center, np.float64)
    und = division_undistort(np.ascontiguousarray(pts, np.float64).reshape(-1, 2), center,
                             float(lens.scale), lens.lam, lens.lam2, lens.lam3)
    und_q = division_undistort(np.ascontiguousarray(quads, np.float64).reshape(-1, 2), center,
                               float(lens.scale), lens.lam, lens.lam2, lens.lam3)
    ua, uu, un, ul = side_frames(und_q.reshape(M, 4, 2))
    return _curvature_kernel(und.reshape(pts.shape), np.ascontiguousarray(valid, bool),
                             ua, uu, un, ul)


@njit(cache=True, error_model="numpy")
def _curvature_kernel(und: np.ndarray, valid: np.ndarray, a: np.ndarray, u: np.ndarray,
                      n: np.ndarray, length: np.ndarray) -> np.ndarray:
    """(S,) c2 of the least-squares parabola s(tau) through each side's points (S, K, 2)."""
    S, K = valid.shape
    out = np.empty(S)
    for k in range(S):
        N = np.zeros((3, 3))
        r = np.zeros(3)
        for j in range(K):
            if not valid[k, j]:
                continue
            dx, dy = und[k, j, 0] - a[k, 0], und[k, j, 1] - a[k, 1]
            tau = 2.0 * (dx * u[k, 0] + dy * u[k, 1]) / length[k] - 1.0
            s = dx * n[k, 0] + dy * n[k, 1]
            x = (1.0, tau, tau * tau - 1.0 / 3.0)
            for p in range(3):
                r[p] += x[p] * s
                for q in range(3):
                    N[p, q] += x[p] * x[q]
        for p in range(3):
            N[p, p] += 1e-9  # keeps N regular for empty sides
        # Cramer's rule for the last unknown
        det = (N[0, 0] * (N[1, 1] * N[2, 2] - N[1, 2] * N[2, 1])
               - N[0, 1] * (N[1, 0] * N[2, 2] - N[1, 2] * N[2, 0])
               + N[0, 2] * (N[1, 0] * N[2, 1] - N[1, 1] * N[2, 0]))
        det2 = (N[0, 0] * (N[1, 1] * r[2] - r[1] * N[2, 1])
                - N[0, 1] * (N[1, 0] * r[2] - r[1] * N[2, 0])
                + r[0] * (N[1, 0] * N[2, 1] - N[1, 1] * N[2, 0]))
        out[k] = det2 / det
    return out


def _normal_magnification(lens: DivisionLens, mid: np.ndarray, n: np.ndarray) -> np.ndarray:
    """(S,) how much ``lens``'s straightening lengthens a step along each side's normal
    n (S, 2) at its edge's midpoint mid (S, 2), at least 1 (and 1 where not finite)."""
    step = lens.undistort(mid + 0.5 * n) - lens.undistort(mid - 0.5 * n)
    mag = np.hypot(step[:, 0], step[:, 1])
    return np.where(np.isfinite(mag), np.maximum(mag, 1.0), 1.0)


def _division(theta: np.ndarray, center: np.ndarray, scale: float) -> DivisionLens:
    """The division lens of parameters theta (3,) = (lam, lam2, lam3)."""
    return DivisionLens(float(theta[0]), center, scale, float(theta[1]), float(theta[2]))


def estimate_division(model: SideModel, quads: np.ndarray, t: np.ndarray,
                      valid: np.ndarray, shape: tuple[int, ...],
                      pool: LensPool | None = None) -> DivisionLens | None:
    """Plumb-line estimate of a division-model lens from all sides' curvature.

    Whatever bends all the board's sides in a consistent radial way is lens
    distortion. The parabola term of every side is, to first order, linear in
    the division parameters; weighted least squares (three Gauss-Newton steps,
    weak zero-mean priors that shrink poorly determined parameters towards no
    distortion) gives them. With a ``pool``, earlier frames' evidence joins the
    fit and this frame's is added.

    Args:
        model: the fitted sides (parabolas where ``order`` is 3), S = 4 M.
        quads: (M, 4, 2) the quads the sides were laid out from, pixels.
        t: (S, K) along-side positions of the edge profiles, pixels.
        valid: (S, K) bool, the profiles to use.
        shape: the image's (height, width, ...).
        pool: optional evidence from earlier frames of the same camera.

    Returns:
        the lens, or None without enough curved sides or with an implausible
        estimate; its ``significance`` says how well the r^2 term is determined.
    """
    if pool is not None and pool.shape != tuple(shape[:2]):
        pool.reset(tuple(shape[:2]))
    pooled_info = pool.info if pool is not None else np.zeros((3, 3))
    pooled_rhs = pool.info_theta if pool is not None else np.zeros(3)
    if not (model.order >= 3).any() and not pooled_info.any():
        return None
    h, w = shape[:2]
    center = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    scale = float(np.hypot(w, h) / 2.0)
    a, u, n, length = side_frames(quads)
    pts = (a[:, None, :] + t[..., None] * u[:, None, :]
           + model.offset(t)[..., None] * n[:, None, :])
    mid = a + 0.5 * length[:, None] * u + model.offset(0.5 * length[:, None]) * n
    use = (model.order >= 3) & (model.count >= 6)
    var = np.where(use, model.cov[:, 2, 2], np.inf) + CURVATURE_FLOOR**2
    theta: np.ndarray = np.zeros(3)  # lam, lam2, lam3
    eps = 1e-3
    # weak priors keep the r^4 and r^6 terms at zero unless the sides really ask for them
    # (the r^6 term lets the model follow a polynomial lens's image corners)
    prior = np.diag([1.0 / 0.5**2, 1.0 / 0.3**2, 1.0 / 0.05**2])
    if not pooled_info.any():
        prior = LONE_FRAME_PRIOR * prior
    info: np.ndarray = np.zeros((3, 3))
    own_info: np.ndarray = np.zeros((3, 3))
    own_grad: np.ndarray = np.zeros(3)
    # each side's farthest profile from the centre, in units of the half diagonal
    side_reach = np.where(valid, np.linalg.norm(pts - center, axis=2), 0.0).max(axis=1) / scale
    for _ in range(3):
        c = _side_curvature(_division(theta, center, scale), pts, quads, valid)
        # the curvatures are compared in straightened pixels, where a side's error is its
        # image error magnified by the straightening, many times over in a strong barrel
        # model's outer field near the fold, where a few sides would decide the pooled
        # lens. Never more weight than the image error's.
        mag = _normal_magnification(_division(theta, center, scale), mid, n)
        weight = np.where(use, 1.0 / (var * mag * mag), 0.0)
        G = np.stack([(_side_curvature(_division(theta + eps * np.eye(3)[k], center, scale),
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
    sd = float(np.sqrt(max(np.linalg.inv(info)[0, 0], 1e-30)))
    lens = _plausible(theta, center, scale, sd, use, side_reach)
    if lens is not None:
        if pool is not None:
            # this frame's own estimate, linearised at theta: own_info^-1 (own_info theta -
            # grad). Only a plausible fit joins the pool: the linearisations of fits that
            # disagree wildly do not add up to a fit of their sides.
            pool.info = pool.info + own_info
            pool.info_theta = pool.info_theta + own_info @ theta - own_grad
        return lens
    if not pooled_info.any():
        return None
    # this frame disagrees with the pool (a close view's far sides, beyond what the model
    # follows): the pool's own estimate, if it is plausible for this frame's sides
    try:
        theta_p = np.linalg.solve(prior + pooled_info, pooled_rhs)
        sd_p = float(np.sqrt(max(np.linalg.inv(prior + pooled_info)[0, 0], 1e-30)))
    except np.linalg.LinAlgError:
        return None
    return _plausible(theta_p, center, scale, sd_p, use, side_reach)


def _plausible(theta: np.ndarray, center: np.ndarray, scale: float, sd: float,
               use: np.ndarray, side_reach: np.ndarray) -> DivisionLens | None:
    """The division lens of theta (3,), or None when it is not a plausible lens for the
    sides ``use`` (S,) bool that reach ``side_reach`` (S,) half diagonals from the centre.
    ``sd``: the standard deviation of lam (for the lens's significance)."""
    if not np.isfinite(theta).all():
        return None
    lam, lam2, lam3 = float(theta[0]), float(theta[1]), float(theta[2])
    if not LAM_RANGE[0] <= lam <= LAM_RANGE[1] or max(abs(lam2), abs(lam3)) > MAX_HIGHER:
        return None
    lens = DivisionLens(lam, center, scale, lam2, lam3, abs(lam) / sd)
    # plausible only if one to one over nearly all the sides it could be fitted to: a model
    # folding inside many of them would straighten those into nonsense. (A 170-degree
    # equidistant lens needs lam near -1.1 and folds at its 90-degree circle, where a close
    # view's outermost sides can lie; those few keep straight sides, see lens_bend.)
    beyond = use & (side_reach >= lens.fold_radius())
    if beyond.sum() > MAX_BEYOND_FOLD * max(int(use.sum()), 1):
        return None
    return lens
