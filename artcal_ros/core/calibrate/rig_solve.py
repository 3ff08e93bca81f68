"""Joint bundle adjustment of a rig: every camera's intrinsics, the extrinsics of each camera
against the reference camera, and one board pose per rig frame shared by its cameras.

A camera ``c`` sees board point ``X`` of frame ``f`` at ``project_c(T_c_ref T_ref_board(f) X)``;
the reference camera's ``T_c_ref`` is the identity and not estimated (that fixes the gauge).
Levenberg-Marquardt with the frame poses eliminated by a Schur complement: a step costs one
dense solve over the intrinsics and extrinsics, however many frames there are.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.calibrate.lm import point_weights, schur_lm
from artcal_ros.core.calibrate.model import (
    DIST_NAMES,
    INTRINSIC_NAMES,
    ViewPoints,
    free_columns,
    free_jacobian,
    project,
    project_with_jacobian,
)


@dataclass(frozen=True)
class RigObservation:
    """One camera's points in one rig frame.

    Attributes:
        camera: the camera's position in the rig's camera list.
        frame: the frame's position in the solve's frame list (its board pose).
        view: the correspondences (``view.index`` is the rig frame index).
    """

    camera: int
    frame: int
    view: ViewPoints


@dataclass(frozen=True)
class RigCamera:
    """One camera's intrinsics in a rig solve.

    Attributes:
        model: lens model; K: (3, 3); dist: (n,) OpenCV order.
        free: the intrinsics estimated (:func:`~.model.free_parameters`); () holds them.
    """

    model: str
    K: np.ndarray
    dist: np.ndarray
    free: tuple[str, ...]


@dataclass(frozen=True)
class RigSolution:
    """The result of :func:`rig_bundle_adjust`.

    Attributes:
        cameras: the cameras with the solved intrinsics.
        extrinsics: (N, 6) T_c_ref of each camera (rvec, tvec metres); row 0 is zeros.
        poses: (F, 6) T_ref_board of each frame (rvec, tvec metres).
        residuals: per observation, (M, 2) measured minus projected, pixels.
        covariance: (p, p) of the global parameters (each camera's free intrinsics in
            order, then the extrinsics of cameras 1..N-1, 6 each), residual variance
            measured from the fit.
        intrinsic_slices: per camera, its columns in ``covariance``.
        extrinsic_slices: per camera, its 6 columns (None for the reference).
        sigma: residual sigma of unit weight.
    """

    cameras: tuple[RigCamera, ...]
    extrinsics: np.ndarray
    poses: np.ndarray
    residuals: tuple[np.ndarray, ...]
    covariance: np.ndarray
    intrinsic_slices: tuple[slice, ...]
    extrinsic_slices: tuple[slice | None, ...]
    sigma: float


def _matrix(x: np.ndarray) -> np.ndarray:
    return np.array([[x[0], 0.0, x[2]], [0.0, x[1], x[3]], [0.0, 0.0, 1.0]])


def compose(board: np.ndarray, ext: np.ndarray) -> np.ndarray:
    """(6,) T_c_board = T_c_ref T_ref_board from (6,) T_ref_board and (6,) T_c_ref."""
    r, t = cv2.composeRT(board[:3], board[3:], ext[:3], ext[3:])[:2]
    return np.concatenate([np.ravel(r), np.ravel(t)])


def _compose_jacobian(board: np.ndarray,
                      ext: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """T_c_board and its (6, 6) derivatives by T_ref_board and by T_c_ref."""
    r3, t3, dr3dr1, dr3dt1, dr3dr2, dr3dt2, dt3dr1, dt3dt1, dt3dr2, dt3dt2 = cv2.composeRT(
        board[:3], board[3:], ext[:3], ext[3:])
    d_board = np.block([[dr3dr1, dr3dt1], [dt3dr1, dt3dt1]])
    d_ext = np.block([[dr3dr2, dr3dt2], [dt3dr2, dt3dt2]])
    return np.concatenate([np.ravel(r3), np.ravel(t3)]), d_board, d_ext


def rig_residuals(obs: list[RigObservation], cameras: tuple[RigCamera, ...],
                  extrinsics: np.ndarray, poses: np.ndarray) -> list[np.ndarray]:
    """Per observation, (M, 2) measured minus projected image points, pixels."""
    out = []
    for o in obs:
        c = cameras[o.camera]
        pose = compose(poses[o.frame], extrinsics[o.camera]) if o.camera else poses[o.frame]
        out.append(o.view.image_points - project(o.view.object_points, pose[:3], pose[3:],
                                                 c.K, c.dist, c.model))
    return out


def rig_bundle_adjust(obs: list[RigObservation], cameras: list[RigCamera],
                      extrinsics: np.ndarray, poses: np.ndarray, *, weighted: bool = False,
                      max_iterations: int = 100, tolerance: float = 1e-12) -> RigSolution:
    """Levenberg-Marquardt over the free intrinsics, the extrinsics and the frame poses.

    Only steps that lower the (weighted) squared error are accepted, so the fit never
    ends worse than its start.

    Args:
        obs: the observations; every frame needs at least one.
        cameras: the rig's cameras (the first is the reference), with their start.
        extrinsics: (N, 6) T_c_ref to start from (row 0 ignored).
        poses: (F, 6) T_ref_board to start from.
        weighted: weight each point by :func:`~.lm.point_weights`.
        max_iterations: at most this many accepted steps.
        tolerance: stop once a step lowers the error by less than this fraction of it.
    """
    n_cam = len(cameras)
    groups = [free_columns(c.model, c.free, len(c.dist)) for c in cameras]
    sizes = [len(g) for g in groups]
    starts = np.cumsum([0, *sizes])
    intr_slices = tuple(slice(int(starts[k]), int(starts[k + 1])) for k in range(n_cam))
    n_intr = int(starts[-1])
    ext_slices = tuple(None if k == 0 else slice(n_intr + 6 * (k - 1), n_intr + 6 * k)
                       for k in range(n_cam))
    p = n_intr + 6 * (n_cam - 1)
    full = [np.array([c.K[0, 0], c.K[1, 1], c.K[0, 2], c.K[1, 2], *c.dist], np.float64)
            for c in cameras]
    x_g: np.ndarray = np.zeros(p)
    for k, grp in enumerate(groups):
        x_g[intr_slices[k]] = [full[k][gi[0]] for gi in grp]
        if ext_slices[k] is not None:
            x_g[ext_slices[k]] = extrinsics[k]
    x_f: np.ndarray = np.array(poses, dtype=np.float64).reshape(-1, 6).copy()
    n_frames = len(x_f)
    sqrt_w = [np.repeat(np.sqrt(point_weights(o.view) if weighted else np.ones(len(o.view))), 2)
              for o in obs]

    def unpack(xg: np.ndarray) -> tuple[tuple[RigCamera, ...], np.ndarray]:
        cams = []
        for k, grp in enumerate(groups):
            f = full[k].copy()
            for gi, value in zip(grp, xg[intr_slices[k]], strict=True):
                f[list(gi)] = value
            cams.append(RigCamera(cameras[k].model, _matrix(f), f[4:].copy(), cameras[k].free))
        ext = np.zeros((n_cam, 6))
        for k in range(1, n_cam):
            ext[k] = xg[ext_slices[k]]
        return tuple(cams), ext

    def cost(xg: np.ndarray, xf: np.ndarray) -> float:
        cams, ext = unpack(xg)
        res = rig_residuals(obs, cams, ext, xf)
        total = float(sum(np.sum((r.ravel() * sw) ** 2) for r, sw in zip(res, sqrt_w,
                                                                        strict=True)))
        return total if np.isfinite(total) else np.inf

    # the global columns each camera's points depend on: its intrinsics, then its extrinsics
    cols_of = []
    for k in range(n_cam):
        cols = list(range(intr_slices[k].start, intr_slices[k].stop))
        es = ext_slices[k]
        if es is not None:
            cols += list(range(es.start, es.stop))
        cols_of.append(np.array(cols, dtype=int))

    def normal_equations(xg: np.ndarray, xf: np.ndarray) -> tuple[
            float, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
        cams, ext = unpack(xg)
        U = np.zeros((p, p))
        g = np.zeros(p)
        W = np.zeros((n_frames, p, 6))
        V = np.zeros((n_frames, 6, 6))
        gb = np.zeros((n_frames, 6))
        total = 0.0
        n_rows = 0
        for o, sw in zip(obs, sqrt_w, strict=True):
            c = cams[o.camera]
            if o.camera:
                pose, d_board, d_ext = _compose_jacobian(xf[o.frame], ext[o.camera])
            else:
                pose, d_board, d_ext = xf[o.frame], np.eye(6), np.zeros((6, 6))
            img, A, B = project_with_jacobian(o.view.object_points, pose[:3], pose[3:],
                                              c.K, c.dist, c.model)
            # Only this camera's intrinsics, its extrinsics and the frame's pose move these
            # points: one small Gram matrix of those columns, scattered into the blocks.
            cols = cols_of[o.camera]
            n_g = len(cols)
            G = np.empty((A.shape[0], n_g + 6))
            n_i = intr_slices[o.camera].stop - intr_slices[o.camera].start
            G[:, :n_i] = free_jacobian(A, groups[o.camera])
            if n_g > n_i:
                G[:, n_i:n_g] = B @ d_ext
            G[:, n_g:] = B @ d_board
            G *= sw[:, None]
            r = (o.view.image_points - img).ravel() * sw
            total += float(r @ r)
            n_rows += len(r)
            # einsum, not BLAS: small products, and BLAS threads fight over shared cores
            H = np.einsum("ij,ik->jk", G, G)
            h = np.einsum("ij,i->j", G, r)
            U[np.ix_(cols, cols)] += H[:n_g, :n_g]
            g[cols] += h[:n_g]
            W[o.frame][cols] += H[:n_g, n_g:]
            V[o.frame] += H[n_g:, n_g:]
            gb[o.frame] += h[n_g:]
        return (total if np.isfinite(total) else np.inf), U, g, W, V, gb, n_rows

    x_g, x_f = schur_lm(x_g, x_f, lambda xg, xf: normal_equations(xg, xf)[:6], cost,
                        max_iterations=max_iterations, tolerance=tolerance, ridge=1e-12)
    current, U, _, W, V, _, n_rows = normal_equations(x_g, x_f)
    # Covariance of the global parameters: the poses eliminated without damping.
    S0 = U - np.einsum("npk,nkl,nql->pq", W, np.linalg.pinv(V), W)
    dof = max(n_rows - p - 6 * n_frames, 1)
    sigma = float(np.sqrt(current / dof))
    try:
        cov = np.linalg.inv(S0) * sigma ** 2 if p else np.zeros((0, 0))
    except np.linalg.LinAlgError:
        cov = np.full((p, p), np.inf)
    cams, ext = unpack(x_g)
    return RigSolution(cams, ext, x_f, tuple(rig_residuals(obs, cams, ext, x_f)), cov,
                       intr_slices, ext_slices, sigma)


def free_names(camera: RigCamera) -> tuple[str, ...]:
    """The free parameters' names in the order of the camera's covariance block."""
    names = INTRINSIC_NAMES + DIST_NAMES[camera.model]
    return tuple(n for n in camera.free if n == "f" or n in names)


def _rt(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return cv2.Rodrigues(np.asarray(x[:3], np.float64))[0], np.asarray(x[3:6], np.float64)


def pair_transform(extrinsics: np.ndarray, a: int, b: int) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) T_b_a, a point in camera ``a``'s frame to camera ``b``'s, from
    (N, 6) T_c_ref of every camera."""
    Ra, ta = _rt(extrinsics[a])
    Rb, tb = _rt(extrinsics[b])
    R = Rb @ Ra.T
    return R, tb - R @ ta


def pair_std_devs(sol: RigSolution, a: int, b: int) -> tuple[np.ndarray, np.ndarray, float]:
    """1-sigma of T_b_a from the solve's covariance: (rotation about the x, y, z axes of
    ``a``'s frame (3,) degrees, translation (3,) metres, baseline metres)."""
    cols = [s for s in (sol.extrinsic_slices[a], sol.extrinsic_slices[b]) if s is not None]
    if not cols or not np.all(np.isfinite(sol.covariance)):
        nan3 = np.full(3, np.nan)
        return nan3, nan3, float("nan")
    idx = np.concatenate([np.arange(s.start, s.stop) for s in cols])
    cov = sol.covariance[np.ix_(idx, idx)]
    R0, t0 = pair_transform(sol.extrinsics, a, b)
    # Numerical derivatives of (rotation error in a's frame, t, |t|) by the parameters.
    J = np.zeros((7, len(idx)))
    eps = 1e-7
    for j in range(len(idx)):
        ext = sol.extrinsics.copy()
        which = [k for k in (a, b) if sol.extrinsic_slices[k] is not None]
        cam = which[j // 6]
        ext[cam, j % 6] += eps
        R1, t1 = pair_transform(ext, a, b)
        dR = R0.T @ R1  # a small rotation: its axis-angle vector from the skew part
        J[:3, j] = 0.5 * np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0],
                                   dR[1, 0] - dR[0, 1]]) / eps
        J[3:6, j] = (t1 - t0) / eps
        J[6, j] = (np.linalg.norm(t1) - np.linalg.norm(t0)) / eps
    c = J @ cov @ J.T
    std = np.sqrt(np.maximum(np.diag(c), 0.0))
    return np.degrees(std[:3]), std[3:6], float(std[6])
