"""Camera models for calibration: correspondences, solutions, projection, single-view poses.

Three models, named as in sensor_msgs/CameraInfo:

- ``plumb_bob``: pinhole + Brown-Conrady distortion, OpenCV order (k1, k2, p1, p2, k3);
  k3 is held at zero unless asked for (the paper's model has k1, k2, p1, p2).
- ``rational_polynomial``: (k1, k2, p1, p2, k3, k4, k5, k6).
- ``equidistant``: OpenCV's fisheye model, (k1, k2, k3, k4).

Skew is always zero. Which parameters a solve estimates is :class:`SolveOptions` (the
``calibrate.*`` parameters, named after ROS camera_calibration's flags); the names in
:func:`free_parameters` drive OpenCV's flags, the bundle adjustment and the covariance.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.camera import LENS_MODELS
from artcal_ros.core.camera import MODELS as MODELS  # re-exported for the solve modules
from artcal_ros.core.errors import CalibrationError, ParameterError

# Names of the intrinsic parameters in the order their standard deviations are reported.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy")
# the coefficient names of every lens model (the registry in core/camera.py)
DIST_NAMES = {name: spec.dist_names for name, spec in LENS_MODELS.items()}

@dataclass(frozen=True)
class ViewPoints:
    """The correspondences of one view.

    Attributes:
        index: position of the view in the caller's list of detections.
        source: where the image came from (for reports).
        object_points: (M, 3) float64, metres, board frame (z = 0).
        image_points: (M, 2) float64, pixels.
        marker_ids: (M,) int64, the marker each point belongs to (on a chessboard or
            ChArUco board: the point's own id).
        sharpness: focus measure of the image (NaN if unknown).
        marker_corners_px: (M, 4, 2) float64 pixels, for marker centres: the corners they
            were measured from (so the centres can be corrected for distortion); else None.
        sigma_px: (M,) float64, the detector's 1-sigma error of each point, pixels (NaN
            where unknown), or None.
    """

    index: int
    source: str
    object_points: np.ndarray
    image_points: np.ndarray
    marker_ids: np.ndarray
    sharpness: float = float("nan")
    marker_corners_px: np.ndarray | None = None
    sigma_px: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.image_points)

    def subset(self, mask: np.ndarray) -> ViewPoints:
        """Only the points ``mask`` selects."""
        corners = None if self.marker_corners_px is None else self.marker_corners_px[mask]
        sigma = None if self.sigma_px is None else self.sigma_px[mask]
        return ViewPoints(self.index, self.source, self.object_points[mask],
                          self.image_points[mask], self.marker_ids[mask], self.sharpness,
                          corners, sigma)

    def with_image_points(self, image_points: np.ndarray) -> ViewPoints:
        """The same view with other image points (M, 2), pixels."""
        return ViewPoints(self.index, self.source, self.object_points, image_points,
                          self.marker_ids, self.sharpness, self.marker_corners_px,
                          self.sigma_px)


@dataclass(frozen=True)
class Solution:
    """Intrinsics and per-view poses from one solve.

    Attributes:
        camera_matrix: (3, 3) float64, pixels.
        dist_coeffs: (n,) float64, OpenCV order for ``model``.
        model: one of :data:`MODELS`.
        rvecs, tvecs: (V, 3) float64, T_cam_board of each view (Rodrigues, metres).
        free: names of the parameters that were estimated (others held fixed).
    """

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    model: str
    rvecs: np.ndarray
    tvecs: np.ndarray
    free: tuple[str, ...]


# The one focal length of a solve with fx = fy (calibrate.fix_aspect_ratio): in a list of
# free parameters it stands for fx and fy together.
TIED_FOCAL = "f"


def radial_names(model: str) -> tuple[str, ...]:
    """The radial coefficients of ``model`` in the order ``k_coefficients`` frees them."""
    return LENS_MODELS[model].radial


def default_radial_terms(model: str) -> int:
    """Radial terms solved when ``k_coefficients`` is 0: k1 k2 for plumb_bob, all otherwise.

    (plumb_bob's k3 only pays for strong distortion and is extrapolated where few points
    reach; the paper's model has k1 k2 p1 p2.)
    """
    return LENS_MODELS[model].default_radial


@dataclass(frozen=True)
class SolveOptions:
    """Which intrinsics a solve estimates; the rest are held (ROS camera_calibration's flags).

    Attributes:
        k_coefficients: radial terms solved, k1..kN (0: the model's default, see
            :func:`default_radial_terms`); plumb_bob allows up to 3, rational_polynomial 6,
            equidistant 4. The terms not solved are held at zero.
        fix_principal_point: cx, cy held at the image centre ((w - 1) / 2, (h - 1) / 2).
        fix_aspect_ratio: fx = fy, solved as one focal length.
        zero_tangent_dist: p1 = p2 = 0 (plumb_bob, rational_polynomial; equidistant has no
            tangential terms, so it is always true there).
    """

    k_coefficients: int = 0
    fix_principal_point: bool = False
    fix_aspect_ratio: bool = False
    zero_tangent_dist: bool = False

    def radial_terms(self, model: str) -> int:
        """Number of radial coefficients solved for ``model``."""
        return self.k_coefficients or default_radial_terms(model)

    def check(self, model: str) -> None:
        """Raise ParameterError if ``k_coefficients`` is out of range for ``model``."""
        complaint = k_coefficients_complaint(model, self.k_coefficients)
        if complaint:
            raise ParameterError(complaint)


def k_coefficients_complaint(model: str, k: int) -> str | None:
    """Why ``calibrate.k_coefficients = k`` does not suit ``model``, or None if it does."""
    if model not in DIST_NAMES:
        return None  # the model itself is refused elsewhere
    names = radial_names(model)
    if 0 <= k <= len(names):
        return None
    default = " ".join(names[:default_radial_terms(model)])
    return (f"parameter 'calibrate.k_coefficients': {k} is out of range for camera_model "
            f"{model}; allowed: 0 (the model's default, {default}) or 1 to {len(names)} "
            f"(k1 to {names[-1]})")


def free_parameters(model: str, k3: bool = False, *,
                    options: SolveOptions | None = None) -> tuple[str, ...]:
    """Names of the parameters a solve of ``model`` estimates, in the order they are reported.

    Args:
        model: one of :data:`MODELS`.
        k3: shorthand for ``SolveOptions(k_coefficients=3)`` with plumb_bob (ignored when
            ``options`` is given, and for the other models).
        options: what the solve holds fixed; :data:`TIED_FOCAL` replaces fx and fy when
            the aspect ratio is fixed.
    """
    if options is None:
        options = SolveOptions(k_coefficients=3 if k3 and model == "plumb_bob" else 0)
    names: list[str] = [TIED_FOCAL] if options.fix_aspect_ratio else ["fx", "fy"]
    if not options.fix_principal_point:
        names += ["cx", "cy"]
    radial = radial_names(model)[:options.radial_terms(model)]
    for n in DIST_NAMES[model]:
        if n in ("p1", "p2") and options.zero_tangent_dist:
            continue
        if n.startswith("k") and n not in radial:
            continue
        names.append(n)
    return tuple(names)


def free_columns(model: str, free: tuple[str, ...],
                 n_dist: int | None = None) -> list[tuple[int, ...]]:
    """For each free parameter, its positions in (fx, fy, cx, cy, *dist).

    Args:
        model: one of :data:`MODELS`.
        free: names as :func:`free_parameters` gives them.
        n_dist: distortion coefficients present (default: all of the model's); free
            names beyond them are left out.
    """
    names = INTRINSIC_NAMES + DIST_NAMES[model][:n_dist]
    return [(0, 1) if n == TIED_FOCAL else (names.index(n),) for n in free
            if n == TIED_FOCAL or n in names]


def free_jacobian(A: np.ndarray, groups: list[tuple[int, ...]]) -> np.ndarray:
    """(R, p) derivatives by the free parameters from those by (fx, fy, cx, cy, *dist).

    Args:
        A: (R, 4 + n) the intrinsic Jacobian (:func:`project_jacobian`).
        groups: :func:`free_columns`; a tied parameter's column is the sum of its members'.
    """
    if all(len(g) == 1 for g in groups):
        return A[:, [g[0] for g in groups]]
    return np.stack([A[:, g[0]] if len(g) == 1 else A[:, list(g)].sum(axis=1)
                     for g in groups], axis=1)


def constrain(camera_matrix: np.ndarray, dist_coeffs: np.ndarray, model: str,
              image_size: tuple[int, int], options: SolveOptions) -> tuple[np.ndarray,
                                                                             np.ndarray]:
    """Intrinsics moved onto the constraints of ``options``, to start a solve from.

    The held parameters get their held values (principal point at the image centre,
    fx = fy at their mean, unsolved distortion terms at zero); the free ones are unchanged.

    Args:
        camera_matrix: (3, 3); dist_coeffs: (n,) OpenCV order for ``model``.
        image_size: (width, height), pixels.

    Returns:
        (K (3, 3), dist (n,)), copies.
    """
    K = np.array(camera_matrix, dtype=np.float64)
    dist = np.array(dist_coeffs, dtype=np.float64).ravel()
    w, h = image_size
    if options.fix_principal_point:
        K[0, 2], K[1, 2] = (w - 1) / 2.0, (h - 1) / 2.0
    if options.fix_aspect_ratio and K[0, 0] != K[1, 1]:
        K[0, 0] = K[1, 1] = 0.5 * (K[0, 0] + K[1, 1])
    free = free_parameters(model, options=options)
    for i, n in enumerate(DIST_NAMES[model][:len(dist)]):
        if n not in free:
            dist[i] = 0.0
    return K, dist


def project(object_points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
            camera_matrix: np.ndarray, dist_coeffs: np.ndarray, model: str) -> np.ndarray:
    """Project board points into the image.

    Args:
        object_points: (M, 3) float64, metres, board frame.
        rvec, tvec: (3,) T_cam_board.
        camera_matrix: (3, 3); dist_coeffs: (n,) for ``model``.

    Returns:
        (M, 2) float64, pixels.
    """
    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    if model == "equidistant":
        img, _ = cv2.fisheye.projectPoints(obj, np.asarray(rvec, np.float64).reshape(3, 1),
                                           np.asarray(tvec, np.float64).reshape(3, 1),
                                           camera_matrix, np.asarray(dist_coeffs).reshape(4, 1))
    else:
        img, _ = cv2.projectPoints(obj, np.asarray(rvec, np.float64), np.asarray(tvec, np.float64),
                                   camera_matrix, np.asarray(dist_coeffs, np.float64))
    return img.reshape(-1, 2)


def project_jacobian(object_points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
                     camera_matrix: np.ndarray, dist_coeffs: np.ndarray,
                     model: str) -> tuple[np.ndarray, np.ndarray]:
    """Derivatives of the projection of one view's points.

    Returns:
        (intrinsic (2M, 4 + n): d pixel / d (fx, fy, cx, cy, dist...),
         extrinsic (2M, 6): d pixel / d (rvec, tvec)); rows alternate x, y per point.
    """
    _, A, B = project_with_jacobian(object_points, rvec, tvec, camera_matrix, dist_coeffs,
                                    model)
    return A, B


def project_with_jacobian(object_points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
                          camera_matrix: np.ndarray, dist_coeffs: np.ndarray,
                          model: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The projection of one view's points and its derivatives, from one OpenCV call.

    Returns:
        (image points (M, 2) float64 pixels, as :func:`project`; intrinsic (2M, 4 + n)
        and extrinsic (2M, 6) derivatives, as :func:`project_jacobian`).
    """
    obj = np.ascontiguousarray(object_points, dtype=np.float64).reshape(-1, 1, 3)
    if model == "equidistant":
        img, J = cv2.fisheye.projectPoints(obj, np.asarray(rvec, np.float64).reshape(3, 1),
                                           np.asarray(tvec, np.float64).reshape(3, 1),
                                           camera_matrix, np.asarray(dist_coeffs).reshape(4, 1))
        # fisheye columns: fx fy cx cy k1..k4 rvec(3) tvec(3) alpha
        return img.reshape(-1, 2), J[:, 0:8], J[:, 8:14]
    img, J = cv2.projectPoints(obj, np.asarray(rvec, np.float64), np.asarray(tvec, np.float64),
                               camera_matrix, np.asarray(dist_coeffs, np.float64))
    # pinhole columns: rvec(3) tvec(3) fx fy cx cy dist(n)
    return img.reshape(-1, 2), J[:, 6:], J[:, 0:6]


def estimate_pose(view: ViewPoints, camera_matrix: np.ndarray, dist_coeffs: np.ndarray,
                  model: str) -> tuple[np.ndarray, np.ndarray]:
    """T_cam_board of one view with the intrinsics held fixed: (rvec (3,), tvec (3,)).

    Both poses a planar target admits (IPPE) are refined in the distorted image and the
    one that fits better is kept.
    """
    if model == "equidistant":
        und = cv2.fisheye.undistortPoints(view.image_points.reshape(-1, 1, 2), camera_matrix,
                                          np.asarray(dist_coeffs).reshape(4, 1))
    else:
        und = cv2.undistortPointsIter(view.image_points.reshape(-1, 1, 2), camera_matrix,
                                      np.asarray(dist_coeffs, np.float64), np.eye(3), np.eye(3),
                                      (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 50,
                                       1e-12))
    n, cand_r, cand_t, _ = cv2.solvePnPGeneric(view.object_points, und.reshape(-1, 2),
                                               np.eye(3), np.zeros(5), flags=cv2.SOLVEPNP_IPPE)
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for k in range(n):
        r, t, err = refine_pose(view, camera_matrix, dist_coeffs, model,
                                np.asarray(cand_r[k]).ravel(), np.asarray(cand_t[k]).ravel())
        if np.isfinite(err) and (best is None or err < best[0]):
            best = (err, r, t)
    if best is None:
        raise CalibrationError(f"no pose found for view {view.source or view.index}")
    return best[1], best[2]


def refine_pose(view: ViewPoints, K: np.ndarray, dist: np.ndarray, model: str,
                rvec: np.ndarray, tvec: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """T_cam_board of one view refined from a starting pose, the intrinsics held fixed.

    Gauss-Newton on the 6 pose parameters in the distorted image, steps halved until the
    error drops.

    Args:
        view: the view's points.
        K: (3, 3); dist: (n,) for ``model``.
        rvec, tvec: (3,) the starting T_cam_board.

    Returns:
        (rvec (3,), tvec (3,), sum of squared residuals px^2, inf if not finite).
    """
    x = np.concatenate([rvec, tvec]).astype(np.float64)
    obj, img = view.object_points, view.image_points

    def sse(e: np.ndarray) -> float:
        total = float(np.sum(e ** 2))
        return total if np.isfinite(total) else np.inf

    projected, _, J = project_with_jacobian(obj, x[:3], x[3:], K, dist, model)
    r = img - projected
    current = sse(r)
    for _ in range(20):
        step, *_ = np.linalg.lstsq(J, r.ravel(), rcond=None)
        for _half in range(10):
            trial = sse(img - project(obj, x[:3] + step[:3], x[3:] + step[3:], K, dist,
                                      model))
            if trial <= current:
                break
            step = step / 2.0
        else:
            break
        x = x + step
        improvement = current - trial
        current = trial
        if improvement <= 1e-14 * max(current, 1e-30):
            break
        projected, _, J = project_with_jacobian(obj, x[:3], x[3:], K, dist, model)
        r = img - projected
    return x[:3].copy(), x[3:].copy(), current
