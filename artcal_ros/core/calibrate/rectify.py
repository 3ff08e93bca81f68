"""Stereo rectification of a calibrated camera pair, for every lens model.

Both cameras are turned half-way towards each other about the axis of their relative
rotation, then together so that the baseline lies along the rectified x axis (y for a
pair one above the other), the smallest turn that does it (Bouguet's rule, as
``cv2.stereoRectify``). Both rectified cameras share one camera matrix K'; its focal
length and principal point show only valid pixels of both images (``alpha = 0`` of
``cv2.stereoRectify``, camera_calibration's default) for the pinhole models, and for
equidistant (fisheye) lenses, whose edge rays can reach past 90 degrees, the smaller
focal length of the two with the image centred between the two optical axes.

The projection matrices follow ROS camera_calibration: ``P1 = [K' | 0]``,
``P2 = [K' | K' t_rect]`` with ``t_rect = (-baseline, 0, 0)`` for a second camera to the
right of the first, so ``P2[0, 3] = Tx = -fx' * baseline``.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from artcal_ros.core.calibrate.rig_result import Rectification
from artcal_ros.core.camera import CameraModel


def _turn_onto(u: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit vector ``u`` onto unit vector ``target``."""
    axis = np.cross(u, target)
    s = float(np.linalg.norm(axis))
    angle = float(np.arctan2(s, float(np.dot(u, target))))
    if s < 1e-15:
        return np.eye(3)
    return cv2.Rodrigues(axis / s * angle)[0]


def rectifying_rotations(R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """(R1, R2, vertical): each camera's frame into the common rectified frame.

    Args:
        R: (3, 3), t: (3,) metres: x_second = R @ x_first + t.
    """
    r = cv2.Rodrigues(np.asarray(R, np.float64))[0].ravel()
    half_first = cv2.Rodrigues(0.5 * r)[0]
    half_second = cv2.Rodrigues(-0.5 * r)[0]
    t_half = half_second @ np.asarray(t, np.float64).ravel()
    vertical = abs(t_half[1]) > abs(t_half[0])
    axis = 1 if vertical else 0
    target = np.zeros(3)
    target[axis] = 1.0 if t_half[axis] > 0 else -1.0
    turn = _turn_onto(t_half / np.linalg.norm(t_half), target)
    return turn @ half_first, turn @ half_second, bool(vertical)


def rectified_points(camera: CameraModel, R_rect: np.ndarray, P: np.ndarray,
                     points_px: np.ndarray) -> np.ndarray:
    """(N, 2) where image points land in the rectified image, pixels (NaN where the lens
    model cannot be inverted or the ray points behind the rectified camera).

    Args:
        camera: the calibrated camera; R_rect: (3, 3) its rectification; P: (3, 4) its
            rectified projection matrix; points_px: (N, 2) image points, pixels.
    """
    pts = np.asarray(points_px, np.float64).reshape(-1, 2)
    if len(pts) == 0:
        return np.zeros((0, 2))
    rays, ok = camera.unproject(pts)
    q = rays @ np.asarray(R_rect, np.float64).T
    with np.errstate(divide="ignore", invalid="ignore"):
        img = q @ np.asarray(P, np.float64)[:, :3].T
        out = img[:, :2] / img[:, 2:3]
    out[~ok | (q[:, 2] <= 1e-9)] = np.nan
    return out


def _edge_points(size: tuple[int, int], n: int = 48) -> list[np.ndarray]:
    """The left, right, top and bottom image edges, ``n`` pixels each."""
    w, h = size
    xs, ys = np.linspace(0.0, w - 1.0, n), np.linspace(0.0, h - 1.0, n)
    return [np.c_[np.zeros(n), ys], np.c_[np.full(n, w - 1.0), ys],
            np.c_[xs, np.zeros(n)], np.c_[xs, np.full(n, h - 1.0)]]


def _valid_window(camera: CameraModel, R_rect: np.ndarray) -> np.ndarray:
    """(x0, x1, y0, y1): the rectangle of normalized rectified coordinates inside the
    camera's image (its edges' innermost points; infinite where an edge has none)."""
    bounds = []
    for k, edge in enumerate(_edge_points(camera.size)):
        rays, ok = camera.unproject(edge)
        q = rays @ R_rect.T
        good = ok & (q[:, 2] > 1e-6)
        coord = q[good, k // 2] / q[good, 2]
        low_side = k % 2 == 0
        if len(coord) == 0:
            bounds.append(-np.inf if low_side else np.inf)
        else:
            bounds.append(float(coord.max() if low_side else coord.min()))
    return np.array(bounds)


def _axis_centre(rotations: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """Mean normalized rectified (x, y) of the two cameras' optical axes."""
    out = []
    for R in rotations:
        q = R @ np.array([0.0, 0.0, 1.0])
        out.append(q[:2] / q[2])
    return np.mean(out, axis=0)


def rectified_camera_matrix(first: CameraModel, second: CameraModel, R1: np.ndarray,
                            R2: np.ndarray, vertical: bool) -> np.ndarray:
    """(3, 3) K' shared by both rectified cameras, for the first camera's image size."""
    w, h = first.size
    f_rect = min(first.K[0, 0], first.K[1, 1], second.K[0, 0], second.K[1, 1])
    centre = _axis_centre((R1, R2))
    if first.model != "equidistant" and second.model != "equidistant":
        a, b = _valid_window(first, R1), _valid_window(second, R2)
        x0, x1 = max(a[0], b[0]), min(a[1], b[1])
        y0, y1 = max(a[2], b[2]), min(a[3], b[3])
        if np.all(np.isfinite([x0, x1, y0, y1])) and x1 > x0 and y1 > y0:
            f_valid = max((w - 1.0) / (x1 - x0), (h - 1.0) / (y1 - y0))
            # a window shrunk to a sliver by an extreme lens is not a sensible view
            if 0.25 * f_rect < f_valid < 4.0 * f_rect:
                f_rect = f_valid
                centre = np.array([0.5 * (x0 + x1), 0.5 * (y0 + y1)])
    return np.array([[f_rect, 0.0, (w - 1.0) / 2.0 - f_rect * centre[0]],
                     [0.0, f_rect, (h - 1.0) / 2.0 - f_rect * centre[1]],
                     [0.0, 0.0, 1.0]])


def rectify_pair(first_name: str, second_name: str, first: CameraModel, second: CameraModel,
                 R: np.ndarray, t: np.ndarray, points_first: np.ndarray,
                 points_second: np.ndarray) -> Rectification:
    """The rectification of a calibrated pair and its epipolar error.

    Args:
        first_name, second_name: the cameras' names.
        first, second: the calibrated cameras.
        R: (3, 3), t: (3,) metres: x_second = R @ x_first + t.
        points_first, points_second: (N, 2) pixels: the same board points seen by both
            cameras in one frame, row by row (the epipolar error's correspondences).
    """
    R1, R2, vertical = rectifying_rotations(R, t)
    K_rect = rectified_camera_matrix(first, second, R1, R2, vertical)
    t_rect = R2 @ np.asarray(t, np.float64).ravel()
    t_rect[1 - int(vertical)] = 0.0  # zero up to rounding by construction
    t_rect[2] = 0.0
    P1 = np.hstack([K_rect, np.zeros((3, 1))])
    P2 = np.hstack([K_rect, (K_rect @ t_rect).reshape(3, 1)])
    rect = Rectification(first_name, second_name, R1, R2, P1, P2, (first.size, second.size),
                         first.model if first.model == second.model else
                         f"{first.model}/{second.model}", vertical, float("nan"), 0)
    rms, n = epipolar_error(first, second, rect, points_first, points_second)
    return replace(rect, epipolar_rms_px=rms, epipolar_points=n)


def epipolar_error(first: CameraModel, second: CameraModel, rect: Rectification,
                   points_first: np.ndarray, points_second: np.ndarray) -> tuple[float, int]:
    """(RMS of :func:`rectified_differences`, pixels; their number)."""
    diff = rectified_differences(first, second, rect, points_first, points_second)
    rms = float(np.sqrt(np.mean(diff ** 2))) if len(diff) else float("nan")
    return rms, len(diff)


def rectified_differences(first: CameraModel, second: CameraModel, rect: Rectification,
                          points_first: np.ndarray, points_second: np.ndarray) -> np.ndarray:
    """(K,) row differences (column differences for a vertical pair) of corresponding
    points after rectification, pixels, second minus first.

    Only points that land inside both rectified images count: the rows of a point outside
    them exist in no rectified image (a fisheye's edge, stretched without bound by the
    rectified pinhole camera, would otherwise decide the figure).

    Args:
        first, second: the calibrated cameras; rect: their rectification.
        points_first, points_second: (N, 2) pixels, the same points in both images.
    """
    a = rectified_points(first, rect.R1, rect.P1, points_first)
    b = rectified_points(second, rect.R2, rect.P2, points_second)
    w, h = rect.image_sizes[0]
    inside = np.ones(len(a), dtype=bool)
    for pts in (a, b):
        with np.errstate(invalid="ignore"):
            inside &= ((pts[:, 0] >= -0.5) & (pts[:, 0] <= w - 0.5)
                       & (pts[:, 1] >= -0.5) & (pts[:, 1] <= h - 0.5))
    return np.asarray((b - a)[inside, 0 if rect.vertical else 1])
