"""The one view geometry: guessed camera, board pose, coverage grid and its threshold.

A live calibration needs views that, together, put board points over the whole
image (so distortion is constrained out to the edges) and that tilt the board
(a fronto-parallel plane leaves the focal length unobservable). This module is
the single definition of how a view is measured before any solve, used by both
sides that judge views:

- the node's :class:`~artcal_ros.core.live.coverage.ViewCollector` (readiness, novelty, tilt,
  the heat map), and
- the calibration (``core.calibrate.views``: view selection, the degeneracy checks;
  ``core.calibrate.pipeline``: the coverage figure and its warning),

so the node cannot call a collection "ready" whose solve then warns that the
coverage is poor. The pieces: one guessed camera (:func:`guess_camera_matrix`),
one pose estimate (planar PnP, IPPE, :func:`view_geometry`), one coverage grid
(:data:`COVERAGE_GRID`, :func:`grid_cells`) and one threshold (:data:`MIN_COVERAGE`).

The pose assumes a rough camera (focal length 0.8 x the larger image side,
principal point at the centre): it only sorts views ("tilted or not", "unlike
the others"), so a focal length off by a third still sorts them correctly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections

COVERAGE_GRID = (8, 6)  # (cols, rows): cells across and down the image
MIN_COVERAGE = 0.6  # share of the grid cells that should hold a point of some view
POINTS_MODES = ("centers", "corners")  # the correspondences a solve may use

# Names of the 3 x 3 regions of the image, row-major, for "what is missing".
REGION_NAMES = ("top-left", "top", "top-right", "left", "centre", "right",
                "bottom-left", "bottom", "bottom-right")


def guess_camera_matrix(image_size: tuple[int, int]) -> np.ndarray:
    """A rough pinhole camera (about 65 degrees across) for view geometry before a solve.

    Args:
        image_size: (width, height), pixels.

    Returns:
        (3, 3) float64 camera matrix, pixels.
    """
    w, h = image_size
    f = 0.8 * max(w, h)
    return np.array([[f, 0.0, (w - 1) / 2.0], [0.0, f, (h - 1) / 2.0], [0.0, 0.0, 1.0]])


def grid_cells(image_points: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    """The cells of :data:`COVERAGE_GRID` that hold at least one of the points.

    Args:
        image_points: (N, 2) pixels.
        image_size: (width, height), pixels.

    Returns:
        (cols * rows,) bool, row-major (cell ``row * cols + col``).
    """
    w, h = image_size
    gx, gy = COVERAGE_GRID
    cells = np.zeros(gx * gy, dtype=bool)
    pts = np.asarray(image_points, dtype=np.float64).reshape(-1, 2)
    cx = np.clip((pts[:, 0] / w * gx).astype(int), 0, gx - 1)
    cy = np.clip((pts[:, 1] / h * gy).astype(int), 0, gy - 1)
    cells[cy * gx + cx] = True
    return cells


def coverage_fraction(cells: np.ndarray) -> float:
    """Share (0..1) of the grid cells that some view covers. ``cells``: (V, C) or (C,) bool."""
    c = np.asarray(cells, dtype=bool)
    if c.ndim == 2:
        c = np.asarray(c.any(axis=0), dtype=bool)
    return float(np.mean(c))


@dataclass(frozen=True)
class ViewGeometry:
    """Rough geometry of one view, from a guessed camera.

    Attributes:
        normal: (3,) unit board normal in the camera frame, facing the camera (z < 0);
            zeros if the pose could not be estimated.
        log_distance: log of the camera-to-board-origin distance, metres (0 without a pose).
        center_px: (2,) mean image position of the view's points, pixels.
        cells: (C,) bool, the :data:`COVERAGE_GRID` cells the view's points fall in.
    """

    normal: np.ndarray
    log_distance: float
    center_px: np.ndarray
    cells: np.ndarray

    @property
    def tilt_x_deg(self) -> float:
        """The board turned left/right: rotation about the camera's y axis (right-handed,
        image down), degrees; 0 facing the camera."""
        return math.degrees(math.atan2(-float(self.normal[0]), -float(self.normal[2])))

    @property
    def tilt_y_deg(self) -> float:
        """The board tipped up/down: rotation about the camera's x axis (right-handed,
        image right), degrees; 0 facing the camera."""
        return math.degrees(math.atan2(float(self.normal[1]), -float(self.normal[2])))


def view_geometry(object_points: np.ndarray, image_points: np.ndarray,
                  image_size: tuple[int, int],
                  camera_matrix: np.ndarray | None = None) -> ViewGeometry:
    """Pose (planar PnP, IPPE) and coverage cells of one view: THE view geometry.

    Args:
        object_points: (N, 3) board points (z = 0), metres; N >= 4 for a pose.
        image_points: (N, 2) their images, pixels.
        image_size: (width, height), pixels.
        camera_matrix: (3, 3) a better camera than :func:`guess_camera_matrix`, if known.
    """
    K = guess_camera_matrix(image_size) if camera_matrix is None else camera_matrix
    obj = np.asarray(object_points, dtype=np.float64).reshape(-1, 3)
    img = np.asarray(image_points, dtype=np.float64).reshape(-1, 2)
    normal: np.ndarray = np.zeros(3)
    log_distance = 0.0
    if len(obj) >= 4:
        ok, rvec, tvec = cv2.solvePnP(obj, img, K, np.zeros(5), flags=cv2.SOLVEPNP_IPPE)
        if ok:
            R, _ = cv2.Rodrigues(rvec)
            n = R[:, 2]
            normal = n if n[2] < 0 else -n  # facing the camera
            log_distance = float(np.log(max(float(np.linalg.norm(tvec)), 1e-6)))
    center = img.mean(axis=0) if len(img) else np.full(2, np.nan)
    return ViewGeometry(normal, log_distance, center, grid_cells(img, image_size))


def point_correspondences(dets: Detections, board: Board) -> tuple[np.ndarray, np.ndarray]:
    """(point ids (M,), image points (M, 2) pixels) of a view's finite points on the board."""
    pids = dets.point_ids
    ok = (pids >= 0) & (pids < len(board.point_ids)) & np.all(np.isfinite(dets.points_px), axis=1)
    return pids[ok], dets.points_px[ok]


def solve_points(dets: Detections, board: Board, points: str) -> tuple[np.ndarray, np.ndarray]:
    """The board and image points a solve takes from one view (as ``views.view_points``).

    Args:
        dets: the view's markers.
        board: the board (ids not on it are ignored).
        points: ``centers`` (one point per marker, needing its corners too) or ``corners``;
            a board with points (chessboard, charuco) gives its points (a ChArUco view
            tracked without its points: its markers).

    Returns:
        (object_points (N, 3) metres, image_points (N, 2) pixels).
    """
    if points not in POINTS_MODES:
        raise ValueError(f"points mode {points!r} is not one of {', '.join(POINTS_MODES)}")
    if board.has_points and (len(dets.point_ids) or not board.n_markers):
        pids, pts = point_correspondences(dets, board)
        return board.object_points(pids), pts
    keep = board.has_ids(dets.ids)
    ids, corners = dets.ids[keep], dets.corners_px[keep]
    has_corners = np.all(np.isfinite(corners), axis=(1, 2))
    if points == "centers":
        centers = dets.centers_px[keep]
        ok = has_corners & np.all(np.isfinite(centers), axis=1)
        return board.object_centers(ids[ok]), centers[ok]
    return (board.object_corners(ids[has_corners]).reshape(-1, 3),
            corners[has_corners].reshape(-1, 2))
