"""Views for calibration: correspondences, per-view checks, pose spread and view selection.

A view needs only enough markers, never the whole board: every decoded marker
names its own place on the board. A recording at 30 fps gives thousands of
nearly identical frames; :func:`select_views` keeps a bounded, diverse set
(tilt, position and distance of the board; coverage of the image; sharpness)
so the solve stays fast without losing accuracy.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.solve import ViewPoints
from artcal_ros.core.camera import CameraModel
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import CalibrationError
from artcal_ros.core.homography import neighbour_misfit

# The view geometry (guessed camera, pose, coverage grid and threshold) is defined once, in
# core.live.view_geometry, for the node's readiness and for the selection and checks here alike.
from artcal_ros.core.live.view_geometry import (
    COVERAGE_GRID,
    POINTS_MODES,
    ViewGeometry,
    grid_cells,
    point_correspondences,
)
from artcal_ros.core.live.view_geometry import view_geometry as one_view_geometry

MIN_MARKERS_PER_VIEW = 6  # enough for a homography plus redundancy to see distortion
MIN_POINTS_PER_VIEW = 8   # the same for single points (chessboard, charuco corners)
MIN_VIEWS = 3  # focal lengths and principal point need three differently tilted views
MIN_TILT_SPREAD_DEG = 5.0  # below this, every view shows the board at the same angle


def view_points(det: Detections, board: Board, points: str, index: int) -> ViewPoints:
    """The correspondences of one image.

    Args:
        det: the markers found in the image.
        board: the board they belong to (ids not on it are ignored).
        points: ``centers`` (one point per marker) or ``corners`` (four); boards with
            points (chessboard, charuco) always give their points, ``marker_ids`` then
            holding each point's id.
        index: position of the view in the caller's list.
    """
    if points not in POINTS_MODES:
        raise CalibrationError(f"points mode {points!r} is not one of {', '.join(POINTS_MODES)}")
    if board.has_points:
        # chessboard and charuco: the saddle points, whatever ``points`` says
        pids, pts = point_correspondences(det, board)
        ok = np.isin(det.point_ids, pids)
        return ViewPoints(index, det.source, board.object_points(pids), pts, pids,
                          det.sharpness, sigma_px=det.point_sigma_px[ok])
    keep = board.has_ids(det.ids)
    if points == "centers":
        img = det.centers_px[keep]
        ok = np.all(np.isfinite(img), axis=1)
        ids = det.ids[keep][ok]
        corners = det.corners_px[keep][ok]
        sigma = det.center_sigma_px[keep][ok]
        has_corners = np.all(np.isfinite(corners), axis=(1, 2))
        ids, img, corners = ids[has_corners], img[ok][has_corners], corners[has_corners]
        return ViewPoints(index, det.source, board.object_centers(ids), img, ids,
                          det.sharpness, corners, sigma[has_corners])
    img4 = det.corners_px[keep]
    ok = np.all(np.isfinite(img4), axis=(1, 2))
    ids = det.ids[keep][ok]
    return ViewPoints(index, det.source, board.object_corners(ids).reshape(-1, 3),
                      img4[ok].reshape(-1, 2), np.repeat(ids, 4), det.sharpness,
                      sigma_px=det.corner_sigma_px[keep][ok].reshape(-1))


def lens_corrected_centers(view: ViewPoints, cam: CameraModel) -> ViewPoints:
    """The view with each marker centre re-measured through the lens model.

    The image of a square's centre is the intersection of its image diagonals only
    without distortion; in a distorted image the corners are undistorted first, the
    diagonals intersected, and the point distorted back (uncorrected, the centre is off
    by up to ~1.5 px in the corners of a strongly distorted 640 x 480 image).
    """
    if view.marker_corners_px is None or len(view) == 0:
        return view
    m = len(view)
    rays, ok = cam.unproject(view.marker_corners_px.reshape(-1, 2))
    h = rays.reshape(m, 4, 3)
    c = np.cross(np.cross(h[:, 0], h[:, 2]), np.cross(h[:, 1], h[:, 3]))
    with np.errstate(all="ignore"):
        c = c / c[:, 2:3]
    good = ok.reshape(m, 4).all(axis=1) & np.all(np.isfinite(c), axis=1)
    new = view.image_points.copy()
    if good.any():
        new[good] = cam.project_cv(c[good])
    return view.with_image_points(new)


LAYOUT_TOLERANCE = 0.35  # of the local marker pitch in the image


def layout_outliers(view: ViewPoints, board: Board) -> np.ndarray:
    """Markers whose image position disagrees with their neighbours' (before any solve).

    Each marker's image position is predicted by an affine map fitted to the markers
    within one cell of it on the board; over so small a patch perspective and lens
    distortion are nearly affine, so a marker off by more than a third of the local
    marker pitch is misplaced or misidentified. Needs no camera model. (Over two cells a
    fisheye's or a strong barrel lens's close views bend the grid enough to flag true
    markers, and whole true views as another board's.)

    Returns:
        (K,) bool over ``np.unique(view.marker_ids)``: True where the marker is an outlier
        (markers with fewer than 4 neighbours present are never flagged).
    """
    ids, inverse = np.unique(view.marker_ids, return_inverse=True)
    k = len(ids)
    pos = np.zeros((k, 2))
    np.add.at(pos, inverse, view.image_points)
    pos /= np.bincount(inverse, minlength=k)[:, None]
    misfit = neighbour_misfit(pos, board.feature_cells(ids).reshape(-1, 2), radius=1)
    bad = np.nan_to_num(misfit, nan=0.0) > LAYOUT_TOLERANCE
    return bad


_TOO_FEW = re.compile(r"\d+ (point|marker)\(s\), needs at least ")


def board_not_found(reason: str) -> bool:
    """Whether a :func:`view_problem` reason says the image gave too few of the board's
    points or markers (the board was not found there, or barely)."""
    return _TOO_FEW.match(reason) is not None


def view_problem(view: ViewPoints, board: Board) -> str | None:
    """Why this view cannot take part in a solve, or None if it can."""
    ids = np.unique(view.marker_ids)
    what = "point" if board.has_points else "marker"
    least = MIN_POINTS_PER_VIEW if board.has_points else MIN_MARKERS_PER_VIEW
    if len(ids) < least:
        return f"{len(ids)} {what}(s), needs at least {least}"
    rc = board.feature_cells(ids)
    if len(np.unique(rc[:, 0])) < 2 or len(np.unique(rc[:, 1])) < 2:
        return f"its {what}s lie on one line of the board (needs two rows and two columns)"
    return None


@dataclass(frozen=True)
class ViewsGeometry:
    """The geometry of several views (:func:`artcal_ros.core.live.view_geometry.view_geometry` of
    each), stacked for selection and the degeneracy checks.

    Attributes:
        normals: (V, 3) unit board normals in the camera frame, facing the camera.
        centers_px: (V, 2) the mean image position of each view's points, pixels.
        log_distance: (V,) log of the camera-to-board distance, metres.
        cells: (V, C) bool, the coverage-grid cells each view's points fall in.
    """

    normals: np.ndarray
    centers_px: np.ndarray
    log_distance: np.ndarray
    cells: np.ndarray


def view_geometry(views: Sequence[ViewPoints], image_size: tuple[int, int],
                  camera_matrix: np.ndarray | None = None, *,
                  cache: GeometryCache | None = None) -> ViewsGeometry:
    """Rough pose and coverage of each view (one definition: core.live.view_geometry), stacked.

    Args:
        views: the views.
        image_size: (width, height), pixels.
        camera_matrix: (3, 3) a better camera than the guessed one, if known.
        cache: geometry already computed: reused for the views it holds unchanged (with
            the same ``image_size`` and ``camera_matrix``), filled in for the others.
    """
    gx, gy = COVERAGE_GRID
    if cache is None:
        cache = GeometryCache()
    each = [cache.get(v, image_size, camera_matrix) for v in views]
    if not each:
        return ViewsGeometry(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0),
                             np.zeros((0, gx * gy), dtype=bool))
    return ViewsGeometry(np.stack([g.normal for g in each]),
                         np.stack([g.center_px for g in each]),
                         np.array([g.log_distance for g in each]),
                         np.stack([g.cells for g in each]))


class GeometryCache:
    """The geometry of views already seen, so a pipeline computes each view's once.

    A view counts as already seen only as the very same :class:`ViewPoints` object (views
    are frozen; a view with points removed or moved is a new object, and gets its own).
    """

    def __init__(self) -> None:
        self._seen: dict[tuple[int, tuple[int, int], bytes | None],
                         tuple[ViewPoints, ViewGeometry]] = {}

    def get(self, view: ViewPoints, image_size: tuple[int, int],
            camera_matrix: np.ndarray | None = None) -> ViewGeometry:
        """The geometry of ``view`` from ``camera_matrix`` (None: the guessed camera),
        computed on first sight."""
        key = (id(view), (int(image_size[0]), int(image_size[1])),
               None if camera_matrix is None
               else np.asarray(camera_matrix, np.float64).tobytes())
        hit = self._seen.get(key)
        if hit is not None and hit[0] is view:
            return hit[1]
        g = one_view_geometry(view.object_points, view.image_points, image_size,
                              camera_matrix)
        # Holding the view keeps its id from being reused by another object.
        self._seen[key] = (view, g)
        return g


def coverage_cells(views: Sequence[ViewPoints], image_size: tuple[int, int]) -> np.ndarray:
    """(V, C) bool: the :data:`COVERAGE_GRID` cells each view's points fall in (no pose)."""
    gx, gy = COVERAGE_GRID
    if not views:
        return np.zeros((0, gx * gy), dtype=bool)
    return np.stack([grid_cells(v.image_points, image_size) for v in views])


def tilt_spread_deg(normals: np.ndarray) -> float:
    """Largest angle between any two board normals, degrees. (V, 3) unit vectors."""
    if len(normals) < 2:
        return 0.0
    cos = np.clip(normals @ normals.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(cos.min())))


def feature_term(board: Board) -> str:
    """What a board's features are called in advice: its markers, tags, circles or points."""
    return {"marker_grid": "markers", "aprilgrid": "tags", "circles": "circles",
            "acircles": "circles"}.get(board.board_type, "points")


def views_problem(views: Sequence[ViewPoints], image_size: tuple[int, int],
                  dropped: Sequence[tuple[int, str]], *, board: Board | None = None,
                  cache: GeometryCache | None = None) -> str | None:
    """Why ``views`` cannot pin down a camera, with what to do; None when they can.

    Tilting the board is advised only when the views' geometry is the problem: when most
    images gave too few points the board was not found there, and no tilt helps.

    Args:
        views: the usable views.
        dropped: (index, reason) of the views already set aside, for the message.
        board: the board, to name its features (markers, points, ...) in the message.
        cache: the views' geometry already computed (the guessed camera's).
    """
    if len(views) < MIN_VIEWS:
        if board is None:
            least = f"{MIN_MARKERS_PER_VIEW} markers or {MIN_POINTS_PER_VIEW} points"
        else:
            n = MIN_POINTS_PER_VIEW if board.has_points else MIN_MARKERS_PER_VIEW
            least = f"{n} {feature_term(board)}"
        why = ""
        reasons = sorted({r for _, r in dropped})
        if dropped:
            why = f" ({len(dropped)} view(s) unusable: {'; '.join(reasons[:3])})"
        not_found = sum(1 for _, r in dropped if board_not_found(r))
        given = len(views) + len(dropped)
        if not_found and 2 * not_found >= given:
            advice = (f"the board is not found in {not_found} of {given} images: check the "
                      "board parameters against the printed board")
        else:
            advice = ("add views with the board tilted 20-45 degrees in different "
                      "directions")
        return (f"{len(views)} usable view(s){why}; at least {MIN_VIEWS} are needed, each "
                f"with >= {least} over two rows and columns of the board; {advice}")
    geo = view_geometry(views, image_size, cache=cache)
    spread = tilt_spread_deg(geo.normals)
    if spread < MIN_TILT_SPREAD_DEG:
        return (f"all {len(views)} views show the board at nearly the same angle (their "
                f"board normals are within {spread:.1f} degrees of each other), which leaves "
                "the focal length undetermined; add views with the board tilted 20-45 "
                "degrees left/right and up/down")
    return None


def check_views(views: Sequence[ViewPoints], image_size: tuple[int, int],
                dropped: Sequence[tuple[int, str]], *,
                cache: GeometryCache | None = None) -> None:
    """Raise CalibrationError if ``views`` cannot pin down a camera (:func:`views_problem`
    says why and what to add)."""
    problem = views_problem(views, image_size, dropped, cache=cache)
    if problem is not None:
        raise CalibrationError(problem)


def select_views(views: Sequence[ViewPoints], image_size: tuple[int, int], max_views: int,
                 *, camera_matrix: np.ndarray | None = None,
                 cache: GeometryCache | None = None) -> list[int]:
    """Choose at most ``max_views`` diverse views (positions into ``views``).

    Greedy: start from the view with the most points, then repeatedly add the view that
    best combines new image coverage (cells of COVERAGE_GRID not yet seen often), a pose
    unlike every view chosen so far (board tilt, position in the image, distance) and
    many points. Views much blurrier than the rest (sharpness below half the median,
    where known) are left out while enough sharper ones remain.

    Args:
        views: candidate views, each usable (see :func:`view_problem`).
        image_size: (width, height), pixels.
        max_views: the bound.
        camera_matrix: (3, 3) a better guess of the camera than the default, if known.
        cache: the views' geometry already computed.

    Returns:
        Sorted positions into ``views``.
    """
    n = len(views)
    if n <= max_views:
        return list(range(n))
    geo = view_geometry(views, image_size, camera_matrix, cache=cache)
    counts = np.array([len(v) for v in views], dtype=np.float64)
    sharp = np.array([v.sharpness for v in views], dtype=np.float64)
    candidates = np.ones(n, dtype=bool)
    known = np.isfinite(sharp)
    if known.sum() > max_views:
        blurred = known & (sharp < 0.5 * np.median(sharp[known]))
        if (~blurred).sum() >= max_views:
            candidates &= ~blurred
    diag = float(np.hypot(*image_size))
    # Feature scaling: 15 degrees of tilt ~ a quarter of the image ~ a factor 1.4 in distance.
    feats = np.hstack([geo.normals * (1.0 / np.radians(15.0)),
                       geo.centers_px / (0.25 * diag),
                       geo.log_distance[:, None] / np.log(1.4)])
    seen = np.zeros(geo.cells.shape[1])
    cell_count = np.maximum(geo.cells.sum(axis=1), 1)
    min_dist = np.full(n, np.inf)
    chosen: list[int] = []
    first = int(np.argmax(np.where(candidates, counts * cell_count, -1.0)))
    pick = first
    while True:
        chosen.append(pick)
        candidates[pick] = False
        seen += geo.cells[pick]
        min_dist = np.minimum(min_dist, np.linalg.norm(feats - feats[pick], axis=1))
        if len(chosen) >= max_views or not candidates.any():
            break
        gain = (geo.cells / (1.0 + seen)).sum(axis=1) / cell_count
        score = gain + 0.5 * np.minimum(min_dist, 3.0) + 0.2 * counts / counts.max()
        pick = int(np.argmax(np.where(candidates, score, -np.inf)))
    return sorted(chosen)
