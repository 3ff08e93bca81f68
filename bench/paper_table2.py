"""The paper's Table 2 on identical rendered poses: four targets, every detector, one camera.

Run by :mod:`bench.paper`. Four targets of the same 10 x 8 point layout (30 mm pitch): our
marker grid (10 x 8 markers of 22.5 mm: 80 centres, 320 corners), a chessboard of 10 x 8
inner corners, a symmetric grid of 10 x 8 circles and an 11 x 9 ChArUco board (10 x 8 inner
corners). Every pose is given to each target about the target's own centre, so the four are
seen from exactly the same place; light, blur and noise draw from the same seed.

A method is a detector (ours through ``artcal_ros.detect``, or OpenCV's own) followed by
a calibration (ours through ``artcal_ros.calibrate``; OpenCV's ``calibrateCamera`` with
its default flags, ``cv2.fisheye.calibrate`` on the fisheye). Columns:

- found: frames where the method returned >= 4 markers (marker grid) or >= 4 points;
  "of 4+": the same among the frames where 4 or more markers of the marker grid are fully
  in the image;
- points/frame: mean correspondences over the frames found;
- std, max: the paper's reprojection figures on a common full point set: the calibrated
  intrinsics held fixed, each pose re-estimated from the exact images of every marker
  corner of the 20 poses that lies in the image, then the residuals' standard deviation
  (per coordinate) and largest length;
- proj RMS, max: projection difference from the true camera over the whole image
  (``projection_difference``, as in ``bench.calibration``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from artcal_ros import Board, calibrate, detect
from artcal_ros.core.calibrate.model import ViewPoints, estimate_pose
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.errors import ArtcalError
from artcal_ros.synth import Camera, Photometry, random_poses, render_view

Pose = tuple[np.ndarray, np.ndarray]
PITCH = 0.03
BOARDS = {
    "marker_grid": Board(cols=10, rows=8, marker_length=0.0225, marker_separation=0.0075),
    "chessboard": Board(board_type="chessboard", cols=10, rows=8, square_length=PITCH),
    "circles": Board(board_type="circles", cols=10, rows=8, square_length=PITCH),
    "charuco": Board(board_type="charuco", cols=11, rows=9, square_length=PITCH,
                     marker_length=0.0225),
}
# the largest target: poses are drawn so that it fits where a pose asks for the whole board
ENVELOPE = BOARDS["charuco"]
# the same light for every target: a 30 % light gradient, 30 % vignetting, a slight
# defocus (disc of 1 px radius) and a 4,000 e- well with 6 e- read noise
PHOTOMETRY = Photometry(gradient=0.3, vignetting=0.3, defocus_px=1.0, full_well=4000.0,
                        read_noise=6.0)
# camera -> (model, radial terms solved by our calibration; 0 the model's default)
MODELS = {"webcam": ("plumb_bob", 0), "hd": ("plumb_bob", 0), "wide": ("plumb_bob", 3),
          "fisheye": ("equidistant", 0), "lowcost": ("plumb_bob", 0)}
MIN_POINTS = 4
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)
# camera_calibration's flags for the classic finder
_CLASSIC = (cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
            | cv2.CALIB_CB_FAST_CHECK)

# (row name, board): ours on every target, then OpenCV's pipeline per target
METHODS = (
    ("ours centres", "marker_grid"), ("ours corners", "marker_grid"),
    ("ours", "chessboard"), ("ours", "circles"), ("ours", "charuco"),
    ("OpenCV ArucoDetector", "marker_grid"),
    ("findChessboardCorners+cornerSubPix", "chessboard"),
    ("findChessboardCornersSB", "chessboard"),
    ("findCirclesGrid", "circles"),
    ("CharucoDetector", "charuco"),
    ("CharucoDetector -0.5 px", "charuco"),
)


def _centre(board: Board) -> np.ndarray:
    x0, y0, x1, y1 = board.extent_m
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])


def board_pose(pose: Pose, board: Board) -> Pose:
    """A pose of the targets' common centre frame as T_cam_board of ``board``."""
    rvec, tvec = pose
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
    return rvec, tvec - R @ _centre(board)


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    return np.asarray(cv2.Rodrigues((axis * angle).reshape(3, 1))[0])


def corner_pose(cam: Camera, corner: int, rng: np.random.Generator) -> Pose:
    """The targets' centre 20 % of the image from one image corner (0..3 clockwise from the
    top-left), the target about 45 % of the image wide, tilted 10-35 degrees."""
    sx, sy = ((-1, -1), (1, -1), (1, 1), (-1, 1))[corner]
    w, h = cam.size
    pix = np.array([[w * (0.5 + 0.3 * sx), h * (0.5 + 0.3 * sy)]])
    ray = cam.unproject(pix)[0][0]
    dist = cam.K[0, 0] * ENVELOPE.size_m[0] / (0.45 * w)
    phi = rng.uniform(0, 2 * math.pi)
    R_board_cam = _rot(np.array([math.cos(phi), math.sin(phi), 0.0]),
                       math.radians(rng.uniform(10, 35))) @ _rot(
        np.array([0.0, 0.0, 1.0]), math.radians(rng.uniform(-20, 20)))
    R = R_board_cam.T
    return cv2.Rodrigues(R)[0].ravel(), ray / np.linalg.norm(ray) * dist


def table_poses(cam: Camera, n: int, rng: np.random.Generator) -> list[Pose]:
    """``n`` poses of the centre frame: 3/5 whole-target views, 1/5 closer than the target
    fits the image, 1/5 at the image corners."""
    n_corner = n // 5
    n_random = n - n_corner
    off = _centre(ENVELOPE)
    poses = []
    for rvec, tvec in random_poses(ENVELOPE, cam, n_random, rng, partial_fraction=0.25):
        R = cv2.Rodrigues(rvec.reshape(3, 1))[0]
        poses.append((rvec, tvec + R @ off))
    poses += [corner_pose(cam, k % 4, rng) for k in range(n_corner)]
    return poses


# --- OpenCV's detectors: image -> (object points (M, 3), image points (M, 2)) or None -----
Found = tuple[np.ndarray, np.ndarray] | None


def _chess_classic(gray: np.ndarray, board: Board) -> Found:
    ok, c = cv2.findChessboardCorners(gray, (board.cols, board.rows), flags=_CLASSIC)
    if not ok:
        return None
    c = c.reshape(-1, 2)
    # camera_calibration's window: half the smallest corner spacing, at most 11 px
    grid = c.reshape(board.rows, board.cols, 2)
    spacing = min(np.linalg.norm(np.diff(grid, axis=0), axis=2).min(),
                  np.linalg.norm(np.diff(grid, axis=1), axis=2).min())
    r = int(max(2, min(11, math.ceil(spacing * 0.5))))
    c = cv2.cornerSubPix(gray, c.reshape(-1, 1, 2).astype(np.float32), (r, r), (-1, -1),
                         _SUBPIX)
    return board.object_points(), c.reshape(-1, 2).astype(np.float64)


def _chess_sb(gray: np.ndarray, board: Board) -> Found:
    ok, c = cv2.findChessboardCornersSB(gray, (board.cols, board.rows),
                                        flags=cv2.CALIB_CB_ACCURACY)
    return (board.object_points(), c.reshape(-1, 2).astype(np.float64)) if ok else None


def _circles(gray: np.ndarray, board: Board) -> Found:
    ok, c = cv2.findCirclesGrid(gray, (board.cols, board.rows),
                                flags=cv2.CALIB_CB_SYMMETRIC_GRID)
    return (board.object_points(), c.reshape(-1, 2).astype(np.float64)) if ok else None


def _charuco(shift: float) -> Callable[[np.ndarray, Board], Found]:
    def find(gray: np.ndarray, board: Board) -> Found:
        cv_board = board.to_cv_board()  # a CharucoBoard for a ChArUco board
        corners, ids, _, _ = cv2.aruco.CharucoDetector(
            cv_board).detectBoard(gray)  # type: ignore[arg-type]
        if ids is None or len(ids) < MIN_POINTS:
            return None
        return board.object_points(ids.ravel()), corners.reshape(-1, 2) - shift
    return find


def _aruco(gray: np.ndarray, board: Board) -> Found:
    det = cv2.aruco.ArucoDetector(board.dictionary, cv2.aruco.DetectorParameters())
    corners, ids, _ = det.detectMarkers(gray)
    if ids is None or len(ids) < MIN_POINTS:
        return None
    obj, img = board.to_cv_board().matchImagePoints(corners, ids)
    return obj.reshape(-1, 3).astype(np.float64), img.reshape(-1, 2).astype(np.float64)


OPENCV: dict[str, Callable[[np.ndarray, Board], Found]] = {
    "OpenCV ArucoDetector": _aruco,
    "findChessboardCorners+cornerSubPix": _chess_classic,
    "findChessboardCornersSB": _chess_sb,
    "findCirclesGrid": _circles,
    "CharucoDetector": _charuco(0.0),
    # OpenCV 4.12 returns ChArUco corners shifted by +0.5 px (opencv/opencv#25539)
    "CharucoDetector -0.5 px": _charuco(0.5),
}


def opencv_calibrate(found: list[tuple[np.ndarray, np.ndarray]], cam: Camera) -> Camera:
    """OpenCV's own calibration of the correspondences: ``calibrateCamera`` with its
    default flags, ``cv2.fisheye.calibrate`` for an equidistant camera."""
    obj = [o.reshape(-1, 1, 3).astype(np.float64 if cam.model == "equidistant"
                                      else np.float32) for o, _ in found]
    img = [i.reshape(-1, 1, 2).astype(obj[0].dtype) for _, i in found]
    if cam.model == "equidistant":
        F = cv2.fisheye
        _, K, D, _, _ = F.calibrate(  # type: ignore[call-overload]
            obj, img, cam.size, None, None,
            flags=F.CALIB_RECOMPUTE_EXTRINSIC | F.CALIB_FIX_SKEW)
    else:
        _, K, D, _, _ = cv2.calibrateCamera(  # type: ignore[call-overload]
            obj, img, cam.size, None, None)
    return Camera(cam.model, K, np.asarray(D).ravel()[:len(cam.dist)], cam.size)


def full_set_errors(est: Any, truth: list[tuple[np.ndarray, np.ndarray]]) -> tuple[float, float]:
    """(std per coordinate, max length) px of the residuals on ``truth`` (object, image
    points per pose) with the intrinsics of ``est`` (a camera) held and each pose
    re-estimated."""
    res = []
    for k, (obj, img) in enumerate(truth):
        view = ViewPoints(k, "", obj, img, np.zeros(len(obj), np.int64))
        try:
            rvec, tvec = estimate_pose(view, est.K, est.dist, est.model)
        except ArtcalError:
            continue
        res.append(img - est.project(obj, rvec, tvec))
    if not res:
        return math.nan, math.nan
    r = np.concatenate(res)
    r = r[np.all(np.isfinite(r), axis=1)]
    return float(np.sqrt(np.mean(np.var(r, axis=0)))), float(np.linalg.norm(r, axis=1).max())


def table2_camera(camera: str, n_poses: int, seed: int) -> list[dict[str, Any]]:
    """Every method's row for one camera (see the module docstring)."""
    cam = Camera.preset(camera)
    model, k_coeffs = MODELS[camera]
    poses = table_poses(cam, n_poses, np.random.default_rng(seed))
    ours: dict[str, list[Any]] = {b: [] for b in BOARDS}
    cv_found: dict[str, list[Found]] = {m: [] for m in OPENCV}
    eligible: list[bool] = []
    truth: list[tuple[np.ndarray, np.ndarray]] = []
    for k, pose in enumerate(poses):
        for name, board in BOARDS.items():
            # the same seed for every target: the same light direction, blur and noise draw
            view = render_view(board, cam, *board_pose(pose, board), photometry=PHOTOMETRY,
                               rng=np.random.default_rng(seed * 1000 + k))
            ours[name].append(detect(view.image, board))
            for method, target in METHODS:
                if target == name and method in OPENCV:
                    cv_found[method].append(OPENCV[method](view.image, board))
            if name == "marker_grid":
                eligible.append(int(view.inside.sum()) >= 4)
                inside = view.inside
                truth.append((board.object_corners(view.ids[inside]).reshape(-1, 3),
                              view.corners_px[inside].reshape(-1, 2)))
    rows = []
    for method, target in METHODS:
        board = BOARDS[target]
        row: dict[str, Any] = {"camera": camera, "method": method, "board": target}
        est: Any = None
        try:
            if method in OPENCV:
                got = [f for f in cv_found[method] if f is not None]
                found = [f is not None for f in cv_found[method]]
                counts = [len(f[0]) for f in got]
                est = opencv_calibrate(got, cam) if len(got) >= 3 else None
            else:
                dets = ours[target]
                sizes = [len(d.ids) if not board.has_points else len(d.point_ids) for d in dets]
                found = [s >= MIN_POINTS for s in sizes]
                per = 4 if method == "ours corners" else 1
                counts = [s * per for s, f in zip(sizes, found, strict=True) if f]
                points = "corners" if method == "ours corners" else "centers"
                used = [d for d, f in zip(dets, found, strict=True) if f]
                est = calibrate(used, board, image_size=cam.size, model=model, points=points,
                                k_coefficients=k_coeffs, cross_validation_folds=0).camera
        except (ArtcalError, cv2.error) as e:
            row["error"] = str(e).strip().splitlines()[-1][:80]
            est = None
        row["found %"] = 100.0 * sum(found) / len(found)
        n_el = sum(eligible)
        row["found of 4+ %"] = (100.0 * sum(f for f, e in zip(found, eligible, strict=True) if e)
                                / n_el if n_el else math.nan)
        row["points/frame"] = float(np.mean(counts)) if counts else 0.0
        if est is None:
            row.update({"std": math.nan, "max": math.nan, "proj RMS": math.nan,
                        "proj max": math.nan})
        else:
            row["std"], row["max"] = full_set_errors(est, truth)
            row["proj RMS"], row["proj max"] = projection_difference(cam, est)
        rows.append(row)
    return rows


def pool_seeds(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One row per (camera, method, board) from the rows of several pose seeds: the mean of
    each column over the seeds, the largest of the ``max`` columns; ``seeds`` counts them."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault((row["camera"], row["method"], row["board"]), []).append(row)
    pooled = []
    for (camera, method, board), same in groups.items():
        row = {"camera": camera, "method": method, "board": board, "seeds": len(same)}
        for key in same[0]:
            values = [r[key] for r in same if isinstance(r.get(key), float)]
            if key in row or not values:
                continue
            finite = [v for v in values if math.isfinite(v)]
            # a seed without a calibration makes the pooled figure missing too
            if len(finite) < len(values):
                row[key] = math.nan
            else:
                row[key] = max(finite) if key in ("max", "proj max") else float(np.mean(finite))
        errors = [r["error"] for r in same if "error" in r]
        if errors:
            row["error"] = f"{len(errors)} of {len(same)} seeds: {errors[0]}"
        pooled.append(row)
    return pooled
