"""Rig calibration of real stereo photographs: OpenCV's stereo chessboard samples.

    python -m bench.rig_real        # the table of docs/real_photos.md, "A stereo pair"

Data: ``../shared/data/real/opencv-stereo-chess`` (Apache-2.0, see its SOURCE.txt): 13 left
and 13 right 640x480 photos of the same instants, a chessboard of 9 x 6 inner corners.
Nobody knows the true extrinsics; what can be compared:

- the rectified epipolar RMS (and the median absolute row difference, which a few misplaced
  corners do not move): after rectification a board point must fall on the same row in
  both images. Every calibration is rectified by the same rule
  (:func:`~artcal_ros.core.calibrate.rectify.rectify_pair`: Bouguet's rotations, alpha 0), so
  the calibrations alone differ, and measured on two sets of corners: OpenCV's
  (``findChessboardCorners`` + ``cornerSubPix`` 11 x 11) and artcal_ros's.
- the baseline in square units (|T| / square length) and the angle between the cameras.

Calibrations: OpenCV's stereo sample (``samples/cpp/stereo_calib.cpp``: ``initCameraMatrix2D``,
then ``stereoCalibrate`` of everything with ``FIX_ASPECT_RATIO | ZERO_TANGENT_DIST |
USE_INTRINSIC_GUESS | SAME_FOCAL_LENGTH | RATIONAL_MODEL | FIX_K3 | FIX_K4 | FIX_K5``);
OpenCV's two-step pipeline (``calibrateCamera`` of each camera, flags 0, then
``stereoCalibrate`` with the intrinsics fixed); artcal_ros's ``calibrate_rig`` from its own
detections (plumb_bob with k1 k2 k3 p1 p2, the published model, and rational_polynomial).
"""

from __future__ import annotations

import glob
from pathlib import Path

import cv2
import numpy as np

from artcal_ros import calibrate_rig
from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.rectify import rectified_differences, rectify_pair
from artcal_ros.core.camera import CameraModel
from artcal_ros.core.detect import Detector
from artcal_ros.core.detections import Detections

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real" / "opencv-stereo-chess"
SQUARE_M = 0.025
CHESS = Board(board_type="chessboard", cols=9, rows=6, square_length=SQUARE_M)
SIZE = (640, 480)
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)
Points = dict[int, np.ndarray]   # point id -> (2,) pixels


def load_pairs() -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(name, left, right) grayscale images of the same instants, by file number."""
    out = []
    for left in sorted(glob.glob(str(REAL / "left" / "left*.jpg"))):
        number = Path(left).stem.removeprefix("left")
        right = REAL / "right" / f"right{number}.jpg"
        out.append((number, cv2.imread(left, cv2.IMREAD_GRAYSCALE),
                    cv2.imread(str(right), cv2.IMREAD_GRAYSCALE)))
    return out


def opencv_corners(image: np.ndarray) -> Points:
    """OpenCV's chessboard corners (the sample's way), by point id; {} if not found."""
    found, c = cv2.findChessboardCorners(image, (9, 6))
    if not found:
        return {}
    c = cv2.cornerSubPix(image, c, (11, 11), (-1, -1), _SUBPIX).reshape(-1, 2)
    return {i: c[i].astype(np.float64) for i in range(len(c))}


def own_corners(det: Detections) -> Points:
    return {int(i): p for i, p in zip(det.point_ids, det.points_px, strict=True)}


def _matched(left: list[Points], right: list[Points]) -> tuple[np.ndarray, np.ndarray]:
    a, b = [], []
    for fa, fb in zip(left, right, strict=True):
        for i in sorted(set(fa) & set(fb)):
            a.append(fa[i])
            b.append(fb[i])
    return np.array(a), np.array(b)


def _stereo_sample(left: list[Points], right: list[Points]) -> tuple[CameraModel, CameraModel,
                                                                    np.ndarray, np.ndarray,
                                                                    float]:
    """OpenCV's stereo_calib.cpp: one stereoCalibrate of intrinsics and extrinsics."""
    keep = [k for k in range(len(left)) if len(left[k]) == 54 and len(right[k]) == 54]
    obj = [CHESS.object_points().astype(np.float32) for _ in keep]
    pa = [np.array([left[k][i] for i in range(54)], np.float32) for k in keep]
    pb = [np.array([right[k][i] for i in range(54)], np.float32) for k in keep]
    K1 = cv2.initCameraMatrix2D(obj, pa, SIZE, 0)
    K2 = cv2.initCameraMatrix2D(obj, pb, SIZE, 0)
    flags = (cv2.CALIB_FIX_ASPECT_RATIO | cv2.CALIB_ZERO_TANGENT_DIST
             | cv2.CALIB_USE_INTRINSIC_GUESS | cv2.CALIB_SAME_FOCAL_LENGTH
             | cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_FIX_K3 | cv2.CALIB_FIX_K4
             | cv2.CALIB_FIX_K5)
    rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
        obj, pa, pb, K1, np.zeros(8), K2, np.zeros(8), SIZE, flags=flags,
        criteria=(cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-5))
    return (CameraModel("rational_polynomial", K1, np.ravel(D1)[:8], SIZE),
            CameraModel("rational_polynomial", K2, np.ravel(D2)[:8], SIZE), R,
            np.ravel(T), float(rms))


def _two_step(left: list[Points], right: list[Points]) -> tuple[CameraModel, CameraModel,
                                                               np.ndarray, np.ndarray, float]:
    """calibrateCamera of each camera, then stereoCalibrate with the intrinsics fixed."""
    cams = []
    for side in (left, right):
        views = [f for f in side if len(f) == 54]
        obj = [CHESS.object_points().astype(np.float32) for _ in views]
        img = [np.array([f[i] for i in range(54)], np.float32) for f in views]
        _, K, D, _, _ = cv2.calibrateCamera(obj, img, SIZE, None, None)
        cams.append((K, np.ravel(D)[:5]))
    keep = [k for k in range(len(left)) if len(left[k]) == 54 and len(right[k]) == 54]
    obj = [CHESS.object_points().astype(np.float32) for _ in keep]
    pa = [np.array([left[k][i] for i in range(54)], np.float32) for k in keep]
    pb = [np.array([right[k][i] for i in range(54)], np.float32) for k in keep]
    (K1, D1), (K2, D2) = cams
    rms, _, _, _, _, R, T, _, _ = cv2.stereoCalibrate(obj, pa, pb, K1, D1, K2, D2, SIZE,
                                                      flags=cv2.CALIB_FIX_INTRINSIC)
    return (CameraModel("plumb_bob", K1, D1, SIZE), CameraModel("plumb_bob", K2, D2, SIZE), R,
            np.ravel(T), float(rms))


def real_pairs() -> list[str]:
    """Markdown rows: each calibration's baseline, angle and rectified epipolar RMS."""
    pairs = load_pairs()
    cv_left = [opencv_corners(a) for _, a, _ in pairs]
    cv_right = [opencv_corners(b) for _, _, b in pairs]
    dets: dict[str, list[Detections]] = {"left": [], "right": []}
    for side, k in (("left", 1), ("right", 2)):
        detector = Detector(CHESS)
        dets[side] = [detector.detect(p[k], source=f"{side}{p[0]}.jpg") for p in pairs]
    own_left = [own_corners(d) for d in dets["left"]]
    own_right = [own_corners(d) for d in dets["right"]]
    point_sets = {"OpenCV's corners": _matched(cv_left, cv_right),
                  "artcal_ros corners": _matched(own_left, own_right)}
    calibrations = {
        "OpenCV stereo_calib sample (rational, one stereoCalibrate)":
            _stereo_sample(cv_left, cv_right),
        "OpenCV calibrateCamera + stereoCalibrate (fixed intrinsics)":
            _two_step(cv_left, cv_right)}
    for label, model, k in (("artcal_ros calibrate_rig, plumb_bob k1 k2 k3 p1 p2",
                             "plumb_bob", 3),
                            ("artcal_ros calibrate_rig, rational_polynomial",
                             "rational_polynomial", 0)):
        res = calibrate_rig(dets, CHESS, image_sizes={"left": SIZE, "right": SIZE},
                            model=model, k_coefficients=k)
        R, t = res.extrinsics["left", "right"]
        calibrations[label] = (res.cameras["left"].camera, res.cameras["right"].camera, R, t,
                               res.reprojection_rms_px)
    rows = ["| calibration | baseline (squares) | angle between cameras (deg) | reprojection "
            "RMS px | " + " | ".join(f"epipolar RMS / median on {s} px" for s in point_sets)
            + " |",
            "|---|---|---|---|" + "---|" * len(point_sets)]
    for label, (ca, cb, R, t, rms) in calibrations.items():
        cells = []
        for a, b in point_sets.values():
            rect = rectify_pair("left", "right", ca, cb, R, t, a, b)
            median = float(np.median(np.abs(rectified_differences(ca, cb, rect, a, b))))
            cells.append(f"{rect.epipolar_rms_px:.4f} / {median:.4f} (f' {rect.P1[0, 0]:.0f})")
        angle = float(np.degrees(np.linalg.norm(cv2.Rodrigues(np.asarray(R))[0])))
        rows.append(f"| {label} | {np.linalg.norm(t) / SQUARE_M:.4f} | {angle:.3f} | {rms:.3f} "
                    f"| {' | '.join(cells)} |")
    n = {s: len(a) for s, (a, _) in point_sets.items()}
    rows.append("")
    rows.append("Corresponding points: " + ", ".join(f"{s} {c}" for s, c in n.items()) + ".")
    return rows


if __name__ == "__main__":
    print("\n".join(real_pairs()))
