"""Chessboard and ChArUco calibrations of real photographs against their published values.

    python -m bench.real_boards        # the tables of docs/real_photos.md, "Chessboard and
                                       # ChArUco boards" (about a minute)

Data (``../shared/data/real/``, see each set's SOURCE.txt):

- ``opencv-stereo-chess``: OpenCV's stereo sample, 13 left and 13 right 640x480 photos of a
  chessboard of 9 x 6 inner corners, 25 mm squares. Published: ``left_intrinsics.yml``
  (OpenCV's calibration sample, ``CALIB_FIX_ASPECT_RATIO``): fx = fy = 535.92,
  cx 342.28, cy 235.57, RMS 0.393 px.
- ``opencv-aruco-tutorial``: four 640x480 photos of a ChArUco board of 5 x 7 squares of
  40 mm with 20 mm DICT_6X6_250 markers. Published: ``tutorial_camera_charuco.yml``
  (flags 0): fx 452.51, fy 456.77, cx 317.70, cy 277.75, RMS 0.182 px.

For each set: OpenCV's own pipeline (``findChessboardCorners`` + ``cornerSubPix`` 11 x 11, or
``CharucoDetector``), and artcal_ros's points, each solved by ``cv2.calibrateCamera`` with the
published flags (same solver, so the points are what differs), and artcal_ros's own solve
(``calibrate()``, plumb_bob with k1 k2 k3 p1 p2, as the published model).
"""

from __future__ import annotations

import glob
from pathlib import Path

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.detect import Detector
from artcal_ros.core.errors import CalibrationError

REAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
CHESS = Board(board_type="chessboard", cols=9, rows=6, square_length=0.025)
CHARUCO = Board(board_type="charuco", cols=5, rows=7, square_length=0.04, marker_length=0.02,
                dictionary_name="DICT_6X6_250")
PUBLISHED = {"chess left": (535.92, 535.92, 342.28, 235.57, 0.393),
             "charuco": (452.51, 456.77, 317.70, 277.75, 0.182)}
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)


def _images(pattern: str) -> list[tuple[str, np.ndarray]]:
    return [(f, cv2.imread(f, cv2.IMREAD_GRAYSCALE)) for f in sorted(glob.glob(pattern))]


def _cv_solve(obj: list[np.ndarray], img: list[np.ndarray], size: tuple[int, int],
              flags: int) -> tuple[float, float, float, float, float, float]:
    """(fx, fy, cx, cy, RMS, 1-sigma of fx) of ``cv2.calibrateCamera``."""
    rms, K, _, _, _, std, _, _ = cv2.calibrateCameraExtended(
        [o.astype(np.float32) for o in obj], [i.astype(np.float32) for i in img], size, None,
        None, flags=flags)
    return (float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2]), float(rms),
            float(max(std.ravel()[0], std.ravel()[1])))   # fy's with a fixed aspect ratio


def _row(name: str, values: tuple[float, ...] | str, ref: float, points: str) -> str:
    if isinstance(values, str):
        return f"| {name} | {points} | {values} | | | | | | |"
    fx, fy, cx, cy, rms = values[:5]
    sigma = f"{values[5]:.2f}" if len(values) > 5 else ""
    return (f"| {name} | {points} | {fx:.2f} | {sigma} | {fy:.2f} | {cx:.2f} | {cy:.2f} | "
            f"{rms:.3f} | {100 * (fx / ref - 1):+.2f} % |")


def chessboard(side: str) -> list[str]:
    """Rows for one camera of the stereo chessboard set."""
    frames = _images(str(REAL / "opencv-stereo-chess" / side / "*.jpg"))
    size = (frames[0][1].shape[1], frames[0][1].shape[0])
    flags = cv2.CALIB_FIX_ASPECT_RATIO
    obj_cv, img_cv, obj_ours, img_ours, dets = [], [], [], [], []
    detector = Detector(CHESS)
    for name, image in frames:
        found, c = cv2.findChessboardCorners(image, (9, 6))
        if found:
            c = cv2.cornerSubPix(image, c, (11, 11), (-1, -1), _SUBPIX)
            obj_cv.append(CHESS.object_points())
            img_cv.append(c.reshape(-1, 2))
        det = detector.detect(image, source=name)
        dets.append(det)
        if len(det.point_ids):
            obj_ours.append(CHESS.object_points(det.point_ids))
            img_ours.append(det.points_px)
    ref = PUBLISHED["chess left"][0]
    n_pts = sum(len(i) for i in img_ours)
    rows = [_row(f"{side}: OpenCV pipeline", _cv_solve(obj_cv, img_cv, size, flags), ref,
                 f"{len(img_cv)} views, {sum(len(i) for i in img_cv)} points"),
            _row(f"{side}: artcal_ros points, calibrateCamera",
                 _cv_solve(obj_ours, img_ours, size, flags), ref,
                 f"{len(img_ours)} views, {n_pts} points")]
    res = calibrate(dets, CHESS, image_size=size, k_coefficients=3, fix_aspect_ratio=True)
    K = res.camera_matrix
    rows.append(_row(f"{side}: artcal_ros solve", (K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                                                   res.reprojection_rms_px,
                                                   float(res.std_devs["fx"])), ref,
                     f"{len(res.views_used)} views"))
    return rows


def charuco() -> list[str]:
    """Rows for the ChArUco tutorial set."""
    frames = _images(str(REAL / "opencv-aruco-tutorial" / "charuco_calib" / "*.jpg"))
    size = (frames[0][1].shape[1], frames[0][1].shape[0])
    cv_detector = cv2.aruco.CharucoDetector(CHARUCO.to_cv_board())
    detector = Detector(CHARUCO)
    obj_cv, img_cv, img_cv_shift, obj_ours, img_ours, dets = [], [], [], [], [], []
    for name, image in frames:
        corners, ids, _, _ = cv_detector.detectBoard(image)
        if ids is not None and len(ids) >= 6:
            obj_cv.append(CHARUCO.object_points(ids.ravel()))
            img_cv.append(corners.reshape(-1, 2))
            img_cv_shift.append(corners.reshape(-1, 2) - 0.5)
        det = detector.detect(image, source=name)
        dets.append(det)
        obj_ours.append(CHARUCO.object_points(det.point_ids))
        img_ours.append(det.points_px)
    ref = PUBLISHED["charuco"][0]
    count = f"{len(img_cv)} views, {sum(len(i) for i in img_cv)} corners"
    rows = [_row("CharucoDetector", _cv_solve(obj_cv, img_cv, size, 0), ref, count),
            _row("CharucoDetector - 0.5 px", _cv_solve(obj_cv, img_cv_shift, size, 0), ref,
                 count),
            _row("artcal_ros points, calibrateCamera", _cv_solve(obj_ours, img_ours, size, 0),
                 ref, f"{len(img_ours)} views, {sum(len(i) for i in img_ours)} corners")]
    try:
        res = calibrate(dets, CHARUCO, image_size=size, k_coefficients=3)
        K = res.camera_matrix
        rows.append(_row("artcal_ros solve", (K[0, 0], K[1, 1], K[0, 2], K[1, 2],
                                              res.reprojection_rms_px,
                                              float(res.std_devs["fx"])), ref, "4 views"))
    except CalibrationError as e:
        rows.append(_row("artcal_ros solve", f"refused: {e}".split(";")[0], ref, "4 views"))
    return rows


def main() -> None:
    head = ("| method | data | fx | fx 1-sigma | fy | cx | cy | RMS px | fx vs published |\n"
            "|---|---|---|---|---|---|---|---|---|")
    fx, fy, cx, cy, rms = PUBLISHED["chess left"]
    print("\nStereo chessboard set (published: left camera)\n")
    print(head)
    print(f"| published (left_intrinsics.yml) | 13 views | {fx} | | {fy} | {cx} | {cy} | {rms} "
          "| |")
    for side in ("left", "right"):
        print("\n".join(chessboard(side)))
    fx, fy, cx, cy, rms = PUBLISHED["charuco"]
    print("\nChArUco tutorial set\n")
    print(head)
    print(f"| published (tutorial_camera_charuco.yml) | 4 views | {fx} | | {fy} | {cx} | {cy} "
          f"| {rms} | |")
    print("\n".join(charuco()))


if __name__ == "__main__":
    main()
