"""Where to hold the board next before the first solve (one view).

The live solve needs two views, but the user needs guidance from the first one. From one
(or two) views :func:`provisional_solution` makes a provisional camera with square pixels and the
principal point at the image centre: the focal length from the views' homographies
(Zhang's constraints, one unknown), then it and the first radial term fitted to the
views; views that cannot tell the focal length (facing the camera) leave the nominal
guess of :func:`~artcal_ros.core.live.view_geometry.guess_camera_matrix` and no
distortion. Each view's pose comes from that camera. :func:`first_pose` ranks
the holdable poses with :func:`~artcal_ros.core.live.guidance.next_pose` by the
uncertainty this camera would have after each: the views' information about the free
intrinsics plus a prior (:data:`PRIOR_SD`, what is known of any camera before it is
measured), so the parameters the views cannot yet determine count with their prior
uncertainty and the ranking favours the views that determine them (tilted views for the
focal lengths, views reaching the corners for the distortion).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.lm import bundle_adjust
from artcal_ros.core.calibrate.model import (
    DIST_NAMES,
    TIED_FOCAL,
    Solution,
    SolveOptions,
    ViewPoints,
    estimate_pose,
    free_columns,
    free_parameters,
    radial_names,
)
from artcal_ros.core.calibrate.quality import intrinsic_covariance, view_blocks
from artcal_ros.core.calibrate.solve import residuals
from artcal_ros.core.errors import CalibrationError
from artcal_ros.core.live.guidance import NextPose, next_pose
from artcal_ros.core.live.view_geometry import guess_camera_matrix

__all__ = ["NOMINAL_NOISE_PX", "PRIOR_SD", "first_pose", "provisional_focal_px",
           "provisional_solution", "start_covariance"]

# 1-sigma prior of each intrinsic before it is measured: focal lengths as a share of the
# focal length (FOCAL_SD for both together, ASPECT_SD for their ratio), the principal
# point as a share of the image's width and height, distortion coefficients as they are.
FOCAL_SD = 0.25
ASPECT_SD = 0.01
CENTRE_SD = 0.05
PRIOR_SD = {"k1": 0.25, "k2": 0.25, "k3": 0.25, "k4": 0.25, "k5": 0.25, "k6": 0.25,
            "p1": 0.005, "p2": 0.005}
NOMINAL_NOISE_PX = 0.05  # point error assumed when the views carry no sigmas
# A view's homography tells the focal length only when the board is tilted: at least
# this much (its constraint's weight grows as sin^2 of the tilt).
MIN_TILT_DEG = 8.0
FOCAL_RANGE = (0.2, 5.0)  # plausible focal lengths, times the image's larger side
# The fit of focal length and first radial term is kept when it tells the focal length to
# within this share (1 sigma; the lens's other terms, left out, bias it by a few times
# that); a view facing the camera cannot.
FIT_FOCAL_SD = 0.03


def provisional_focal_px(views: Sequence[ViewPoints], image_size: tuple[int, int]) -> float:
    """The focal length (pixels) that makes the views' homographies rotations, with square
    pixels and the principal point at the image centre; the nominal guess when no view
    is tilted enough to tell it or the answer is implausible.

    Args:
        views: planar views (object points z = 0), at least 4 points each.
        image_size: (width, height), pixels.
    """
    w, h = image_size
    f0 = float(guess_camera_matrix(image_size)[0, 0])
    # pixels centred on the principal point and scaled by the guess, so that the unknown
    # y = (f0 / f)^2 is near 1 and the constraints' weights compare across images
    to_norm = np.array([[1 / f0, 0, -(w - 1) / 2 / f0], [0, 1 / f0, -(h - 1) / 2 / f0],
                        [0, 0, 1]])
    rows_a, rows_b = [], []
    for v in views:
        if len(v) < 4:
            continue
        H, _ = cv2.findHomography(v.object_points[:, :2], v.image_points, 0)
        if H is None or not np.all(np.isfinite(H)):
            continue
        Hn = np.asarray(to_norm @ H, np.float64)
        h1, h2 = Hn[:, 0], Hn[:, 1]
        scale = 0.5 * (h1 @ h1 + h2 @ h2)
        if not scale > 0:
            continue
        h1, h2 = h1 / math.sqrt(scale), h2 / math.sqrt(scale)
        # h1^T W h2 = 0 and h1^T W h1 = h2^T W h2 with W = diag(y, y, 1)
        rows_a += [h1[0] * h2[0] + h1[1] * h2[1],
                   h1[0] ** 2 + h1[1] ** 2 - h2[0] ** 2 - h2[1] ** 2]
        rows_b += [-h1[2] * h2[2], h2[2] ** 2 - h1[2] ** 2]
    a, b = np.array(rows_a), np.array(rows_b)
    if len(a) == 0 or float(np.sqrt(a @ a)) < math.sin(math.radians(MIN_TILT_DEG)) ** 2:
        return f0
    y = float(a @ b) / float(a @ a)
    if not y > 0:
        return f0
    f = f0 / math.sqrt(y)
    lo, hi = FOCAL_RANGE
    return f if lo * max(w, h) <= f <= hi * max(w, h) else f0


def provisional_solution(views: Sequence[ViewPoints], image_size: tuple[int, int], *,
                         model: str = "plumb_bob",
                         options: SolveOptions | None = None) -> Solution:
    """The provisional camera of a few views: square pixels, the principal point at the
    image centre, the focal length and first radial term fitted to the views (from
    :func:`provisional_focal_px`'s focal length) when they tell the focal length, else
    the nominal guess and no distortion; each view's pose from that camera. ``free`` as
    a solve with ``options`` frees them.

    Args:
        views: at least one view with at least 4 points.
        image_size: (width, height), pixels.
        model: the lens model the solve will use.
    """
    w, h = image_size
    f = provisional_focal_px(views, image_size)
    K = np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    D = np.zeros(len(DIST_NAMES[model]))
    fitted = _fitted(list(views), K, D, _poses(views, K, D, model), model, image_size)
    if fitted is not None:
        K, D, rvecs, tvecs = fitted
    else:  # the homography's focal length is no better where the fit cannot tell it
        K = guess_camera_matrix(image_size)
        rvecs, tvecs = _poses(views, K, D, model)
    return Solution(K, D, model, rvecs, tvecs,
                    free_parameters(model, options=options or SolveOptions()))


def _poses(views: Sequence[ViewPoints], K: np.ndarray, D: np.ndarray, model: str
           ) -> tuple[np.ndarray, np.ndarray]:
    """Each view's pose (rvecs (V, 3), tvecs (V, 3)) from the camera K, D."""
    poses = [estimate_pose(v, K, D, model) for v in views]
    return (np.array([r for r, _ in poses]).reshape(-1, 3),
            np.array([t for _, t in poses]).reshape(-1, 3))


def _fitted(views: list[ViewPoints], K: np.ndarray, D: np.ndarray,
            poses: tuple[np.ndarray, np.ndarray], model: str, image_size: tuple[int, int]
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(K, D, rvecs, tvecs) of the bundle adjustment of one focal length and the first
    radial term from K, D and ``poses``; None when it fails or the views do not tell the
    focal length to within :data:`FIT_FOCAL_SD`."""
    free = (TIED_FOCAL, radial_names(model)[0])
    try:
        K1, D1, rv, tv = bundle_adjust(views, K, D, model, free=free, poses=poses,
                                       max_iterations=30, tolerance=1e-8)
        sol = Solution(K1, D1, model, rv, tv, free)
        cov, _ = intrinsic_covariance(views, sol, residuals(views, sol))
    except (CalibrationError, np.linalg.LinAlgError, ValueError, cv2.error):
        return None
    f = float(K1[0, 0])
    lo, hi = FOCAL_RANGE
    if not (np.all(np.isfinite(K1)) and np.all(np.isfinite(D1))
            and lo * max(image_size) <= f <= hi * max(image_size)
            and math.sqrt(max(float(cov[0, 0]), 0.0)) <= FIT_FOCAL_SD * f):
        return None
    return K1, D1, rv, tv


def start_covariance(views: Sequence[ViewPoints], sol: Solution, image_size: tuple[int, int],
                     *, weighted: bool = False) -> tuple[np.ndarray, float]:
    """(covariance (p, p) of the free intrinsics in the order of ``sol.free``, point sigma
    of unit weight): the views' information (poses eliminated) plus the prior
    :data:`PRIOR_SD`, as :func:`~artcal_ros.core.calibrate.quality.intrinsic_covariance`
    gives it for a solve.

    The point sigma is not measured (a provisional camera's residuals are not the
    detector's): 1 for weighted points (their weights are 1 / sigma^2), else the views'
    median sigma, else :data:`NOMINAL_NOISE_PX`.
    """
    groups = free_columns(sol.model, sol.free)
    p = len(groups)
    sigmas = np.concatenate([v.sigma_px for v in views if v.sigma_px is not None]
                            or [np.zeros(0)])
    sigmas = sigmas[np.isfinite(sigmas)]
    sigma = 1.0 if weighted else (float(np.median(sigmas)) if len(sigmas)
                                  else NOMINAL_NOISE_PX)
    info = np.zeros((p, p))
    for v, r, t in zip(views, sol.rvecs, sol.tvecs, strict=True):
        A, _, W, Vi, _ = view_blocks(v, r, t, sol, groups, weighted=weighted)
        info += A.T @ A - W @ Vi @ W.T
    prior = _prior_covariance(sol, image_size)
    cov = np.linalg.inv(info / sigma ** 2 + np.linalg.inv(prior))
    return cov, sigma


def _prior_covariance(sol: Solution, image_size: tuple[int, int]) -> np.ndarray:
    """(p, p) prior covariance of the free intrinsics (order of ``sol.free``)."""
    f = float(sol.camera_matrix[0, 0])
    w, h = image_size
    common, half_diff = (FOCAL_SD * f) ** 2, (ASPECT_SD * f) ** 2 / 4
    cov = np.zeros((len(sol.free), len(sol.free)))
    for i, n in enumerate(sol.free):
        for j, m in enumerate(sol.free):
            if {n, m} <= {"fx", "fy"}:  # fx, fy = F +- d / 2: common F, small difference d
                cov[i, j] = common + (half_diff if n == m else -half_diff)
            elif i == j:
                cov[i, j] = (common if n == TIED_FOCAL else (CENTRE_SD * w) ** 2 if n == "cx"
                             else (CENTRE_SD * h) ** 2 if n == "cy"
                             else PRIOR_SD.get(n, 0.25) ** 2)
    return cov


def first_pose(views: Sequence[ViewPoints], board: Board, image_size: tuple[int, int], *,
               model: str = "plumb_bob", options: SolveOptions | None = None,
               weighted: bool = False) -> NextPose | None:
    """The holdable pose whose view would lower the provisional camera's projection
    uncertainty (views and prior) the most: :func:`next_pose` before a solve.

    Args:
        views: the views so far (one or two; more work too), at least 4 points each.
        board: the board being shown; image_size: (width, height), pixels.
        model, options: what the solve will estimate.
        weighted: the points are weighted by their sigmas (as the solve will weight them).

    Returns:
        the suggestion, or None without views or when no candidate shows the board.
    """
    views = [v for v in views if len(v) >= 4]
    if not views:
        return None
    sol = provisional_solution(views, image_size, model=model, options=options)
    covariance = start_covariance(views, sol, image_size, weighted=weighted)
    return next_pose(views, sol, board, image_size, weighted=weighted, covariance=covariance)
