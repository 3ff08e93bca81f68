"""Levenberg-Marquardt bundle adjustment of intrinsics and poses, with point weights."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from artcal_ros.core.calibrate.model import (
    ViewPoints,
    estimate_pose,
    free_columns,
    free_jacobian,
    project,
    project_with_jacobian,
)


def point_weights(view: ViewPoints) -> np.ndarray:
    """(M,) least-squares weight of each point: 1 / sigma^2, sigma floored at 0.01 px.

    Points of unknown sigma get the view's median weight (1 where no sigma is known).
    """
    if view.sigma_px is None:
        return np.ones(len(view))
    sigma = np.maximum(np.asarray(view.sigma_px, dtype=np.float64), 0.01)
    known = np.isfinite(sigma)
    if not known.any():
        return np.ones(len(view))
    w = np.where(known, 1.0 / np.where(known, sigma, 1.0) ** 2, np.nan)
    return np.where(known, w, float(np.median(w[known])))


def view_sigma_factors(views: list[ViewPoints], res: list[np.ndarray], *,
                       min_points: int = 8,
                       bounds: tuple[float, float] = (0.5, 3.0)) -> np.ndarray:
    """(V,) factor by which each view's sigmas are off, from a weighted solve's residuals.

    A per-view variance component: the view's weighted squared residuals over its degrees
    of freedom (2 M coordinates less the 6 of its pose) estimate the square of the factor.
    The detector's sigmas come from each side's fit alone; the views where they are too
    small (dim, defocused or compressed frames, close views of few large markers) show it
    in their residuals. Factors are relative to the median view's (a common factor changes
    no solve) and clipped to ``bounds``; views with fewer than ``min_points`` points or
    without sigmas (None or all NaN) keep 1.

    Args:
        views: the views of a weighted solve; res: their residuals, (M, 2) pixels each.
    """
    out = np.ones(len(views))
    known = np.array([v.sigma_px is not None and bool(np.isfinite(v.sigma_px).any())
                      and len(v) >= min_points for v in views])
    for k in np.flatnonzero(known):
        chi2 = float(np.sum(point_weights(views[k]) * np.sum(np.asarray(res[k]) ** 2, axis=1)))
        out[k] = np.sqrt(chi2 / (2 * len(views[k]) - 6))
    if known.any():
        out[known] /= float(np.median(out[known]))
    return np.clip(out, *bounds)


def reweighted(views: list[ViewPoints], res: list[np.ndarray], *,
               huber: float = 1.5) -> list[ViewPoints]:
    """The views with their sigmas re-scaled to a weighted solve's residuals ``res``.

    Each view's sigmas are multiplied by its :func:`view_sigma_factors` factor; then a
    point whose residual exceeds ``huber`` times that sigma (per axis) has its sigma grown
    by sqrt(z / huber), z its residual in sigmas: Huber's weight, so a corner the detector
    misjudged pulls the solve linearly, not quadratically. Views without sigmas are
    returned as they are.

    Args:
        views: the views of a weighted solve, with the detector's sigmas (not re-scaled
            ones: the factors are measured against the sigmas given); res: their
            residuals, (M, 2) pixels each.
    """
    factors = view_sigma_factors(views, res)
    out = []
    for v, r, f in zip(views, res, factors, strict=True):
        if v.sigma_px is None:
            out.append(v)
            continue
        sigma = np.asarray(v.sigma_px, dtype=np.float64) * f
        z = np.linalg.norm(r, axis=1) / (np.sqrt(2.0) * np.maximum(sigma, 0.01))
        grow = np.sqrt(np.maximum(np.nan_to_num(z) / huber, 1.0))
        out.append(replace(v, sigma_px=sigma * grow))
    return out


def bundle_adjust(views: list[ViewPoints], K0: np.ndarray, D0: np.ndarray, model: str,
                   *, free: tuple[str, ...], weighted: bool = False,
                   poses: tuple[np.ndarray, np.ndarray] | None = None,
                   max_iterations: int = 100,
                   tolerance: float = 1e-12) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray]:
    """Levenberg-Marquardt over the free intrinsics and every view's pose.

    Used for the equidistant model (OpenCV's fisheye calibration re-initialises the
    poses at every iteration and fails outright when the distortion wanders) and to
    weight points by their measured uncertainty (OpenCV's solvers cannot). Only steps
    that lower the error are accepted. Poses are eliminated by a Schur complement, so a
    step costs one small dense solve however many views there are.

    Args:
        free: names of the intrinsics to estimate (:func:`free_parameters`; the others
            stay at K0, D0, and a tied fx = fy moves both: start from K0 with fx = fy).
        weighted: weight each point by :func:`point_weights`.
        poses: (rvecs (V, 3), tvecs (V, 3)) to start from; estimated if None.
        max_iterations: at most this many accepted steps.
        tolerance: stop once a step lowers the weighted squared error by less than this
            fraction of it.

    Returns:
        (K (3, 3), dist (n,), rvecs (V, 3), tvecs (V, 3)).
    """
    if poses is None:
        est = [estimate_pose(v, K0, D0, model) for v in views]
        x_ex = np.array([np.concatenate([r, t]) for r, t in est])
    else:
        x_ex = np.hstack([np.asarray(poses[0]), np.asarray(poses[1])]).astype(np.float64)
    x_all = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], *D0], dtype=np.float64)
    groups = free_columns(model, free, len(D0))
    x_in = np.array([x_all[g[0]] for g in groups])
    sqrt_w = [np.repeat(np.sqrt(point_weights(v) if weighted else np.ones(len(v))), 2)
              for v in views]

    def unpack(xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        full = x_all.copy()
        for g, value in zip(groups, xi, strict=True):
            full[list(g)] = value
        K = np.array([[full[0], 0.0, full[2]], [0.0, full[1], full[3]], [0.0, 0.0, 1.0]])
        return K, full[4:].copy()

    def cost(xi: np.ndarray, xe: np.ndarray) -> float:
        K, D = unpack(xi)
        total = 0.0
        for v, pose, sw in zip(views, xe, sqrt_w, strict=True):
            r = (v.image_points - project(v.object_points, pose[:3], pose[3:], K, D,
                                          model)).ravel() * sw
            total += float(np.sum(r ** 2))
        return total if np.isfinite(total) else np.inf

    def normal_equations(xi: np.ndarray, xe: np.ndarray) -> tuple[
            float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        # One projection per view gives the residuals and both Jacobians.
        K, D = unpack(xi)
        U = np.zeros((p, p))
        g = np.zeros(p)
        W = np.empty((len(views), p, 6))
        V = np.empty((len(views), 6, 6))
        gb = np.empty((len(views), 6))
        total = 0.0
        for k, (v, pose, sw) in enumerate(zip(views, xe, sqrt_w, strict=True)):
            img, A, B = project_with_jacobian(v.object_points, pose[:3], pose[3:], K, D,
                                              model)
            A = free_jacobian(A, groups) * sw[:, None]
            B = B * sw[:, None]
            r = (v.image_points - img).ravel() * sw
            total += float(np.sum(r ** 2))
            U += A.T @ A
            g += A.T @ r
            W[k] = A.T @ B
            V[k] = B.T @ B
            gb[k] = B.T @ r
        return (total if np.isfinite(total) else np.inf), U, g, W, V, gb

    p = len(x_in)
    x_in, x_ex = schur_lm(x_in, x_ex, normal_equations, cost, max_iterations=max_iterations,
                          tolerance=tolerance)
    K, D = unpack(x_in)
    return K, D, x_ex[:, :3].copy(), x_ex[:, 3:].copy()


# (error, U (p, p), g (p,), W (n, p, 6), V (n, 6, 6), gb (n, 6)) of the weighted residuals at
# (global parameters, per-block 6-vectors): the blocks of the normal equations.
NormalEquations = tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def schur_lm(x_g: np.ndarray, x_f: np.ndarray,
             normal_equations: Callable[[np.ndarray, np.ndarray], NormalEquations],
             cost: Callable[[np.ndarray, np.ndarray], float], *, max_iterations: int,
             tolerance: float, ridge: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt over global parameters and independent 6-vector blocks (poses).

    The blocks are eliminated by a Schur complement, all at once, so a step costs one dense
    solve of the global parameters however many blocks there are. Marquardt's damping scales
    each diagonal; only steps that lower ``cost`` are taken.

    Args:
        x_g: (p,) the global parameters to start from; x_f: (n, 6) the blocks.
        normal_equations: the blocks of J^T J and J^T r at a point (:data:`NormalEquations`).
        cost: the weighted squared error at a point (inf where it cannot be computed).
        max_iterations: at most this many accepted steps.
        tolerance: stop once a step lowers the error by less than this fraction of it.
        ridge: added to every block's diagonal (a block seen by too few points stays
            invertible).

    Returns:
        (x_g, x_f) at the end.
    """
    lam = 1e-3
    eye6 = np.eye(6)
    current, U, g, W, V, gb = normal_equations(x_g, x_f)
    for _ in range(max_iterations):
        done = False
        improved = False
        while lam < 1e10:
            Vi = np.linalg.inv(V + lam * V * eye6 + ridge * eye6)
            WVi = W @ Vi
            S = U + lam * np.diag(np.diag(U)) - np.einsum("npk,nqk->pq", WVi, W)
            rhs = g - np.einsum("npk,nk->p", WVi, gb)
            try:
                d_g = np.linalg.solve(S, rhs) if len(x_g) else np.zeros(0)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            d_f = np.einsum("nij,nj->ni", Vi, gb - np.einsum("npk,p->nk", W, d_g))
            trial = cost(x_g + d_g, x_f + d_f)
            if trial < current:
                x_g, x_f = x_g + d_g, x_f + d_f
                done = current - trial < tolerance * max(current, 1e-30)
                lam = max(lam / 3.0, 1e-9)
                improved = True
                break
            lam *= 4.0
        if not improved or done:
            break
        current, U, g, W, V, gb = normal_equations(x_g, x_f)
    return x_g, x_f
