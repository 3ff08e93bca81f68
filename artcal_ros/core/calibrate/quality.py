"""Honest quality figures of a calibration: uncertainty, hold-out error, accuracy vs truth.

- :func:`intrinsic_covariance`: covariance of the estimated intrinsics from the
  Jacobian of the solve (poses eliminated by a Schur complement), scaled by the
  measured residual variance. Works for every model, fisheye included.
- :func:`cross_validate`: k-fold over views; each held-out view's pose is fitted
  with the fold's intrinsics held fixed, and its points' error is reported.
- :func:`projection_difference`: the accuracy metric against a known camera
  (RMS and max over a dense grid of the whole image of the distance between where
  the true and the estimated camera project the same rays).
- :func:`fold_radius_px`: where a distortion model stops being one-to-one.
- :func:`uncertainty_map`: the projection uncertainty at every point of the image.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from artcal_ros.core.calibrate.model import free_columns, free_jacobian, refine_pose
from artcal_ros.core.calibrate.solve import (
    Solution,
    ViewPoints,
    bundle_adjust,
    estimate_pose,
    point_weights,
    project,
    project_jacobian,
)
from artcal_ros.core.camera import CameraModel, HasCamera, camera_of, lens_spec

# A fold's LM stops once a step gains less than this fraction of its error: the hold-out
# RMS is then settled to 6 digits (the final solve runs to 1e-12).
FOLD_TOLERANCE = 1e-8


def solution_camera(sol: Solution, image_size: tuple[int, int]) -> CameraModel:
    """The camera of a solve, every coefficient of its model present (fixed ones as zeros)."""
    dist = np.zeros(lens_spec(sol.model).n_dist)
    d = np.asarray(sol.dist_coeffs, dtype=np.float64).ravel()[:len(dist)]
    dist[:len(d)] = d
    return CameraModel(sol.model, sol.camera_matrix, dist, image_size)


def image_grid(size: tuple[int, int], step_px: float) -> np.ndarray:
    """(N, 2) a regular grid over the whole image, corners and edges included, pixels."""
    w, h = size
    xs = np.linspace(0.0, w - 1.0, max(2, round((w - 1) / step_px) + 1))
    ys = np.linspace(0.0, h - 1.0, max(2, round((h - 1) / step_px) + 1))
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.ravel(), gy.ravel()], axis=1)


def projection_difference(true_cam: CameraModel | HasCamera, est_cam: CameraModel | HasCamera, *,
                          step_px: float = 10.0) -> tuple[float, float]:
    """Accuracy of an estimated camera against the true one, pixels: (RMS, max).

    Over a grid of the true camera's whole image (every ``step_px`` pixels, corners
    included) each pixel's ray is unprojected with the true camera and projected with the
    estimated one; the figure is the distance between the two image points. Grid points
    where the true model cannot be inverted exactly are skipped.
    """
    true = camera_of(true_cam)
    est = camera_of(est_cam)
    pix = image_grid(true.size, step_px)
    rays, ok = true.unproject(pix)
    d = np.linalg.norm(est.project_cv(rays[ok]) - pix[ok], axis=1)
    d = d[np.isfinite(d)]
    if len(d) == 0:
        return float("nan"), float("nan")
    return float(np.sqrt(np.mean(d ** 2))), float(d.max())


def view_blocks(v: ViewPoints, rvec: np.ndarray, tvec: np.ndarray, sol: Solution,
                groups: list[tuple[int, ...]], *, weighted: bool = False
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One view's blocks of the normal equations, each row weighted as the solve weights it:
    A (2M, p) by the free intrinsics (``groups``: :func:`free_columns` of ``sol``), B (2M, 6)
    by the view's pose, W = A'B, Vi = (B'B)^+ and the rows' weights sw (2M,) (square roots);
    A'A - W Vi W' is the view's information about the intrinsics with its pose eliminated.
    """
    sw = np.repeat(np.sqrt(point_weights(v) if weighted else np.ones(len(v))), 2)
    A, B = project_jacobian(v.object_points, rvec, tvec, sol.camera_matrix, sol.dist_coeffs,
                            sol.model)
    A = free_jacobian(A, groups) * sw[:, None]
    B = B * sw[:, None]
    W = A.T @ B
    return A, B, W, np.linalg.pinv(B.T @ B), sw


def intrinsic_covariance(views: Sequence[ViewPoints], sol: Solution,
                         res: Sequence[np.ndarray], *, weighted: bool = False,
                         by_marker: bool = False) -> tuple[np.ndarray, float]:
    """Covariance of the free intrinsics of a solve, in the order of ``sol.free``.

    The residual variance is measured (not assumed), so the figures stay honest when the
    detector's sigmas are off by a common factor.

    Args:
        views: the views of the solve; res: their residuals, (M, 2) pixels each.
        weighted: the solve weighted points by :func:`point_weights`.
        by_marker: the errors of one marker's points may be correlated (its corners come
            from the same side fits): the covariance is the sandwich S^-1 M S^-1, M summed
            over markers of the outer product of each marker's residuals through the
            Jacobian (poses eliminated), instead of S^-1 times the residual variance.

    Returns:
        (covariance (p, p), residual sigma per coordinate of unit weight).
    """
    groups = free_columns(sol.model, sol.free)
    p = len(groups)
    U = np.zeros((p, p))
    S = np.zeros((p, p))
    M = np.zeros((p, p))
    n_obs = 0
    sse = 0.0
    for v, r, t, e in zip(views, sol.rvecs, sol.tvecs, res, strict=True):
        A, B, W, Vi, sw = view_blocks(v, r, t, sol, groups, weighted=weighted)
        rw = np.asarray(e).ravel() * sw
        sse += float(np.sum(rw ** 2))
        U += A.T @ A
        S += W @ Vi @ W.T
        if by_marker:
            # Each row's score on the intrinsics with the view's pose projected out.
            score = (A - B @ (Vi @ W.T)) * rw[:, None]
            _, marker = np.unique(np.repeat(v.marker_ids, 2), return_inverse=True)
            per_marker = np.zeros((int(marker.max()) + 1 if len(marker) else 0, p))
            np.add.at(per_marker, marker, score)
            M += per_marker.T @ per_marker
        n_obs += A.shape[0]
    dof = max(n_obs - p - 6 * len(views), 1)
    sigma = float(np.sqrt(sse / dof))
    info = U - S
    try:
        inv = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return np.full((p, p), np.inf), sigma
    if by_marker:  # residuals are smaller than the errors by the fitted degrees of freedom
        return inv @ M @ inv * (n_obs / dof), sigma
    return inv * sigma ** 2, sigma


def parameter_effect_px(sol: Solution, image_size: tuple[int, int],
                        cov: np.ndarray) -> tuple[np.ndarray, float, float]:
    """How much the uncertainty moves the image, pixels.

    Returns:
        (per free parameter, the largest image shift its 1-sigma change causes over the
         image (p,); RMS and max over the image of the 1-sigma projection uncertainty of
         all parameters together).
    """
    pix, A = _free_projection_jacobian(sol, image_size, max(image_size) / 24.0)
    if len(pix) == 0:
        return np.full(len(sol.free), np.inf), float("inf"), float("inf")
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    per_param = np.array([float(np.max(np.hypot(A[0::2, k], A[1::2, k]))) * std[k]
                          for k in range(A.shape[1])])
    sigma = _point_sigma(A, cov)
    return per_param, float(np.sqrt(np.mean(sigma ** 2))), float(sigma.max())


def uncertainty_map(sol: Solution, image_size: tuple[int, int], cov: np.ndarray, *,
                    step_px: float = 20.0) -> tuple[np.ndarray, np.ndarray]:
    """The 1-sigma projection uncertainty at every point of a grid over the image, pixels.

    Each grid pixel's ray (unprojected with the solved camera) is projected again with the
    intrinsics' covariance ``cov`` (free parameters, order of ``sol.free``): the figure is
    sqrt(var x + var y) of that image point. Pixels whose ray cannot be found are left out.

    Returns:
        (grid pixels (N, 2), sigma (N,)).
    """
    pix, A = _free_projection_jacobian(sol, image_size, step_px)
    if len(pix) == 0:
        return pix, np.zeros(0)
    return pix, _point_sigma(A, cov)


def _free_projection_jacobian(sol: Solution, image_size: tuple[int, int],
                              step_px: float) -> tuple[np.ndarray, np.ndarray]:
    """(grid pixels (N, 2) whose ray is found, d(projection)/d(free intrinsics) (2N, p))."""
    cam = solution_camera(sol, image_size)
    pix = image_grid(image_size, step_px)
    rays, ok = cam.unproject(pix)
    groups = free_columns(sol.model, sol.free)
    if not np.any(ok):
        return np.zeros((0, 2)), np.zeros((0, len(groups)))
    A, _ = project_jacobian(rays[ok], np.zeros(3), np.zeros(3), sol.camera_matrix,
                            sol.dist_coeffs, sol.model)
    return pix[ok], free_jacobian(A, groups)


def _point_sigma(A: np.ndarray, cov: np.ndarray) -> np.ndarray:
    var = np.einsum("ij,jk,ik->i", A, cov, A)
    return np.sqrt(np.maximum(var[0::2] + var[1::2], 0.0))


def cross_validate(views: Sequence[ViewPoints], sol: Solution, *, folds: int = 5, seed: int = 0,
                   weighted: bool = False) -> float:
    """k-fold hold-out reprojection RMS over views, pixels (NaN with fewer than 4 views).

    Each fold is solved from the other views (starting from ``sol``); every held-out view's
    pose is then fitted with that fold's intrinsics fixed (starting from its pose in
    ``sol``), and its points' errors pooled.
    """
    n = len(views)
    if n < 4:
        return float("nan")
    k = min(folds, n)
    order = np.random.default_rng(seed).permutation(n)
    sq: list[np.ndarray] = []
    for f in range(k):
        test = set(order[f::k].tolist())
        train_idx = [i for i in range(n) if i not in test]
        train = [views[i] for i in train_idx]
        try:
            # Start from the full solve's intrinsics and poses: a few LM steps suffice.
            K, D, _, _ = bundle_adjust(train, sol.camera_matrix, sol.dist_coeffs, sol.model,
                                       free=sol.free, weighted=weighted,
                                       poses=(sol.rvecs[train_idx], sol.tvecs[train_idx]),
                                       tolerance=FOLD_TOLERANCE)
            fold = Solution(K, D, sol.model, sol.rvecs[train_idx], sol.tvecs[train_idx],
                            sol.free)
        except Exception:  # a fold that cannot be solved says the set is fragile
            return float("inf")
        for i in sorted(test):
            v = views[i]
            # The full solve's pose of this view is a few Gauss-Newton steps from its pose
            # under the fold's intrinsics; from scratch only if that start fails.
            rvec, tvec, err = refine_pose(v, fold.camera_matrix, fold.dist_coeffs, fold.model,
                                          sol.rvecs[i], sol.tvecs[i])
            if not np.isfinite(err):
                rvec, tvec = estimate_pose(v, fold.camera_matrix, fold.dist_coeffs,
                                           fold.model)
            r = v.image_points - project(v.object_points, rvec, tvec, fold.camera_matrix,
                                         fold.dist_coeffs, fold.model)
            sq.append(np.sum(r ** 2, axis=1))
    return float(np.sqrt(np.mean(np.concatenate(sq))))


def fold_radius_px(cam: CameraModel, *, max_angle_deg: float = 89.0) -> float:
    """Smallest distance from the principal point at which the model folds back, pixels.

    Rays are traced outwards along 16 directions; a distortion model is only usable where
    the image radius keeps growing with the ray's angle. Returns inf if it never folds
    within ``max_angle_deg`` of the optical axis.
    """
    theta = np.radians(np.linspace(0.0, max_angle_deg, 400))[1:]
    r = np.tan(theta)
    fold = np.inf
    for phi in np.linspace(0.0, 2 * np.pi, 16, endpoint=False):
        rays = np.stack([r * np.cos(phi), r * np.sin(phi), np.ones_like(r)], axis=1)
        px = cam.project_cv(rays)
        dist = np.linalg.norm(px - cam.K[:2, 2], axis=1)
        back = np.nonzero(np.diff(dist) <= 0)[0]
        if len(back):
            fold = min(fold, float(dist[back[0]]))
    return fold
