"""Chessboard, ChArUco, AprilGrid and circle grids against renderer truth, with OpenCV alike.

    python -m bench.boards            # the numbers in docs/benchmarks.md, "Other boards"
    python -m bench.boards --quick    # fewer views
    python -m bench.boards --circles  # only the circle grid table
    python -m bench.boards --calibration  # only the calibration table

Fresh renders (seeds the unit tests do not use) through the ``webcam`` preset (640 x 480,
strong barrel distortion) and the ``hd`` preset, under two photometric conditions:
``clean`` (the renderer's default: sharp, light noise, clutter behind the board) and
``realistic`` (defocus disc of 1.5 px radius, JPEG quality 85, a 40 % light gradient, 30 %
vignetting, a 4,000 e- well with 6 e- read noise).

1. Chessboard (9 x 6 inner corners, 40 mm squares), whole-board views: share of frames
   found and saddle-point RMS error over the points found, for artcal_ros,
   ``findChessboardCorners`` + ``cornerSubPix`` (5 x 5 and 11 x 11 windows, OpenCV's
   tutorial settings) and ``findChessboardCornersSB``. A method's points are matched to the
   nearest true point (so the classic finder's own id order does not matter).
2. ChArUco (7 x 5 squares of 50 mm, 37 mm DICT_6X6_1000 markers), half the views partial:
   corners per frame, frames where artcal_ros finds fewer than ``CharucoDetector``, RMS
   error and wrong ids (a corner more than 1 px from the true image of its id) for both.
   OpenCV 4.12's ``CharucoDetector`` returns corners shifted by +0.5 px in x and y
   (opencv/opencv#25539, fixed after 4.12 by #28380); its error is given as returned and
   with that shift removed.
3. Chessboards with tiny squares (4.5 to 6 px in the image, whole board in view, tilted up
   to 45 degrees, clean light): share of frames found by each method.
4. AprilGrid (Kalibr's 6 x 6 tag36h11 grid of 88 mm tags, spacing 0.3), half the views
   partial: tags found against tags wholly in view, wrong ids (a tag more than a quarter of
   its side from the true tag of its id), tags with a corner more than 1 px off, and corner
   RMS over all tags found with the right id, for artcal_ros and OpenCV's ``ArucoDetector``
   (DICT_APRILTAG_36h11, SUBPIX refinement) with its default ``markerBorderBits`` 1 and with
   2, Kalibr's printed border. OpenCV's corners are matched to the nearest true corner of
   the same tag (its corner order for this print is its own).
5. Circle grids (:mod:`bench.circle_grids`): a 9 x 6 symmetric grid (40 mm spacing) and
   OpenCV's 4 x 11 asymmetric grid (30 mm spacing), whole-board views: share found and
   centre RMS for artcal_ros, the fitted ellipse's own centre (no perspective correction)
   and OpenCV's ``findCirclesGrid`` blob centres; wrong ids and half-turned views.
6. Calibration from each target: 20 realistic whole-board views per camera of a marker grid
   (9 x 6 markers of 30 mm, 10 mm gaps), the chessboard, a 10 x 7 ChArUco board (40 mm
   squares, 30 mm markers), a 9 x 6 AprilGrid (30 mm tags, spacing 0.33) and the two
   circle grids above, boards of about the same size, at poses drawn with the same seed;
   projection difference RMS against the true camera (plumb_bob k1 k2 p1 p2).

Full run: 20 views a case (about 25 minutes on a loaded 2-core machine); --quick: 6.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.detect import Detector
from artcal_ros.core.errors import CalibrationError
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
from bench.circle_grids import ACIRCLES, CIRCLES, circle_grid

CONDITIONS = {
    "clean": Photometry.clean(),
    "realistic": Photometry(gradient=0.4, vignetting=0.3, defocus_px=1.5, jpeg_quality=85,
                            full_well=4000.0, read_noise=6.0),
}
CHESS = Board(board_type="chessboard", cols=9, rows=6, square_length=0.04)
CHARUCO = Board(board_type="charuco", cols=7, rows=5, square_length=0.05, marker_length=0.037)
APRILGRID = Board(board_type="aprilgrid", cols=6, rows=6, marker_length=0.088,
                  marker_separation=0.0264)
_SUBPIX = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01)


def _rms(errors: list[np.ndarray]) -> float:
    e = np.concatenate(errors) if errors else np.zeros(0)
    return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


def _nearest(points: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.linalg.norm(points.reshape(-1, 1, 2) - truth[None], axis=2).min(axis=1)


def chessboard(camera: str, condition: str, views: int, seed: int) -> dict[str, str]:
    """Found share and RMS error per method on whole-board chessboard views."""
    cam = Camera.preset(camera)
    rng = np.random.default_rng(seed)
    detector = Detector(CHESS)
    found = dict.fromkeys(("artcal_ros", "subpix 5x5", "subpix 11x11", "SB"), 0)
    errors: dict[str, list[np.ndarray]] = {k: [] for k in found}
    size = (CHESS.cols, CHESS.rows)
    for r, t in random_poses(CHESS, cam, views, rng, partial_fraction=0.0):
        view = render_view(CHESS, cam, r, t, photometry=CONDITIONS[condition], rng=rng)
        det = detector.detect(view.image)
        if len(det.point_ids):
            found["artcal_ros"] += 1
            errors["artcal_ros"].append(
                np.linalg.norm(det.points_px - view.points_px[det.point_ids], axis=1))
        gray = view.image
        ok, corners = cv2.findChessboardCorners(gray, size)
        if ok:
            for win, name in ((5, "subpix 5x5"), (11, "subpix 11x11")):
                c = cv2.cornerSubPix(gray, corners.copy(), (win, win), (-1, -1), _SUBPIX)
                found[name] += 1
                errors[name].append(_nearest(c, view.points_px))
        ok, corners = cv2.findChessboardCornersSB(gray, size, flags=cv2.CALIB_CB_ACCURACY)
        if ok:
            found["SB"] += 1
            errors["SB"].append(_nearest(corners, view.points_px))
    return {k: f"{found[k]}/{views} {_rms(errors[k]):.4f}" for k in found}


def charuco(camera: str, condition: str, views: int, seed: int) -> dict[str, str]:
    """Corners per frame, losses, RMS and wrong ids: artcal_ros against CharucoDetector."""
    cam = Camera.preset(camera)
    rng = np.random.default_rng(seed)
    detector = Detector(CHARUCO)
    cv_detector = cv2.aruco.CharucoDetector(CHARUCO.to_cv_board())
    n_ours = n_cv = fewer = wrong_ours = wrong_cv = 0
    err_ours: list[np.ndarray] = []
    err_cv: list[np.ndarray] = []
    err_cv_shifted: list[np.ndarray] = []
    for r, t in random_poses(CHARUCO, cam, views, rng, partial_fraction=0.5):
        view = render_view(CHARUCO, cam, r, t, photometry=CONDITIONS[condition], rng=rng)
        det = detector.detect(view.image)
        e = np.linalg.norm(det.points_px - view.points_px[det.point_ids], axis=1)
        wrong_ours += int((e > 1.0).sum())
        err_ours.append(e[e <= 1.0])
        corners, ids, _, _ = cv_detector.detectBoard(view.image)
        k = 0 if ids is None else len(ids)
        if k:
            assert corners is not None and ids is not None
            c = corners.reshape(-1, 2)
            ec = np.linalg.norm(c - view.points_px[ids.ravel()], axis=1)
            es = np.linalg.norm(c - 0.5 - view.points_px[ids.ravel()], axis=1)
            wrong_cv += int((es > 1.0).sum())
            err_cv.append(ec[es <= 1.0])
            err_cv_shifted.append(es[es <= 1.0])
        n_ours += len(det.point_ids)
        n_cv += k
        fewer += int(len(det.point_ids) < k)
    return {"corners/frame ours": f"{n_ours / views:.1f}",
            "corners/frame CharucoDetector": f"{n_cv / views:.1f}",
            "frames ours < CharucoDetector": str(fewer),
            "RMS ours": f"{_rms(err_ours):.4f}",
            "RMS CharucoDetector": f"{_rms(err_cv):.4f}",
            "RMS CharucoDetector -0.5 px": f"{_rms(err_cv_shifted):.4f}",
            "wrong ids ours / CharucoDetector": f"{wrong_ours} / {wrong_cv}"}


def _aruco_36h11(border_bits: int) -> cv2.aruco.ArucoDetector:
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = border_bits
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    return cv2.aruco.ArucoDetector(dictionary, params)


def aprilgrid(camera: str, condition: str, views: int, seed: int) -> dict[str, str]:
    """Tags found, wrong ids and corner RMS: artcal_ros against OpenCV's ArucoDetector."""
    cam = Camera.preset(camera)
    rng = np.random.default_rng(seed)
    detector = Detector(APRILGRID)
    methods = {"ours": None, "OpenCV border 1": _aruco_36h11(1),
               "OpenCV border 2": _aruco_36h11(2)}
    found = dict.fromkeys(methods, 0)
    wrong = dict.fromkeys(methods, 0)
    off = dict.fromkeys(methods, 0)  # right tag, a corner more than 1 px from the truth
    errors: dict[str, list[np.ndarray]] = {m: [] for m in methods}
    visible = 0
    for r, t in random_poses(APRILGRID, cam, views, rng, partial_fraction=0.5):
        view = render_view(APRILGRID, cam, r, t, photometry=CONDITIONS[condition], rng=rng)
        visible += int(view.inside.sum())
        at = {int(k): j for j, k in enumerate(view.ids)}
        for name, cv_detector in methods.items():
            if cv_detector is None:
                det = detector.detect(view.image)
                ids, quads = det.ids, det.corners_px
            else:
                cv_quads, cv_ids, _ = cv_detector.detectMarkers(view.image)
                ids = np.zeros(0, int) if cv_ids is None else cv_ids.ravel()
                quads = np.array(cv_quads).reshape(-1, 4, 2)
            for k, quad in zip(ids, quads, strict=True):
                true = view.corners_px[at[int(k)]] if int(k) in at else None
                side = 0.0 if true is None else float(
                    np.linalg.norm(true - np.roll(true, 1, axis=0), axis=1).min())
                if true is None or np.linalg.norm(quad.mean(0) - true.mean(0)) > side / 4:
                    wrong[name] += 1  # not the tag at that place
                    continue
                e = np.linalg.norm(quad[:, None] - true[None], axis=2).min(axis=1)
                errors[name].append(e)
                found[name] += 1
                off[name] += int(e.max() > 1.0)
    out = {"tags in view": str(visible)}
    for name in methods:
        out[f"found {name}"] = str(found[name])
        out[f"RMS {name}"] = f"{_rms(errors[name]):.4f}"
        out[f"corners > 1 px {name}"] = str(off[name])
    out["wrong ids ours / border 1 / border 2"] = " / ".join(str(wrong[m]) for m in methods)
    return out


def small_squares(camera: str, views: int, seed: int) -> dict[str, str]:
    """Frames with the whole board found, squares of about 5.5 px."""
    cam = Camera.preset(camera)
    board = Board(board_type="chessboard", cols=9, rows=6, square_length=0.01)
    x0, y0, x1, y1 = board.extent_m
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    rng = np.random.default_rng(seed)
    detector = Detector(board)
    found = dict.fromkeys(("artcal_ros", "findChessboardCorners", "findChessboardCornersSB"), 0)
    errors: list[np.ndarray] = []
    n = 0
    while n < views:
        axis = np.array([*rng.normal(size=2), 0.0])
        rvec = (axis / np.linalg.norm(axis) * np.radians(rng.uniform(5, 45))
                + np.array([0, 0, np.radians(rng.uniform(-30, 30))]))
        R = cv2.Rodrigues(rvec)[0]
        d = rng.uniform(0.8, 1.4) * cam.K[0, 0] * board.square_length / 6.5
        off = np.array([rng.uniform(-0.25, 0.25) * cam.width / cam.K[0, 0] * d,
                        rng.uniform(-0.25, 0.25) * cam.height / cam.K[1, 1] * d, d])
        tvec = off - R @ centre
        view = render_view(board, cam, rvec, tvec, photometry=CONDITIONS["clean"], rng=rng)
        if not view.points_inside.all():
            continue
        n += 1
        det = detector.detect(view.image)
        if len(det.point_ids):
            found["artcal_ros"] += 1
            errors.append(np.linalg.norm(det.points_px - view.points_px[det.point_ids], axis=1))
        found["findChessboardCorners"] += int(cv2.findChessboardCorners(view.image, (9, 6))[0])
        found["findChessboardCornersSB"] += int(
            cv2.findChessboardCornersSB(view.image, (9, 6))[0])
    out = {k: f"{v}/{views}" for k, v in found.items()}
    out["RMS artcal_ros px"] = f"{_rms(errors):.4f}"
    return out


TARGETS = {
    "marker_grid": Board(cols=9, rows=6, marker_length=0.03, marker_separation=0.01),
    "chessboard": CHESS,
    "charuco": Board(board_type="charuco", cols=10, rows=7, square_length=0.04,
                     marker_length=0.03),
    "aprilgrid": Board(board_type="aprilgrid", cols=9, rows=6, marker_length=0.03,
                       marker_separation=0.01),
    "circles": CIRCLES,
    "acircles": ACIRCLES,
}
# OpenCV's 4 x 11 asymmetric grid is long along its y axis: held upright and centred in a
# landscape image it never reaches the image's sides, and no detector's points can then pin
# the distortion down (its true centres plus 0.02 px noise calibrate the webcam to 0.42 px).
# Users hold it across the image, as OpenCV's sample photos show it.
TARGET_ROLL_DEG = {"acircles": 90.0}


def calibration(camera: str, views: int, seeds: Sequence[int],
                names: Sequence[str] = tuple(TARGETS)) -> dict[str, str]:
    """Projection difference (RMS px) of a calibration from each target, over several seeds.

    One seed's 20 views decide a projection difference only loosely (the marker grid's
    webcam figure spreads 0.015 - 0.060 px over four seeds), so each target is solved from
    the poses of every seed and reported as the RMS over the seeds with their range, and
    as a ratio to the marker grid's RMS on the same poses.
    """
    cam = Camera.preset(camera)
    diffs: dict[str, list[float]] = {name: [] for name in ("marker_grid", *names)}
    failed: dict[str, str] = {}
    for seed in seeds:
        for name in diffs:
            board = TARGETS[name]
            rng = np.random.default_rng(seed)
            detector = Detector(board)
            dets = [detector.detect(render_view(board, cam, r, t,
                                                photometry=CONDITIONS["realistic"],
                                                rng=rng).image)
                    for r, t in random_poses(board, cam, views, rng, partial_fraction=0.0,
                                             roll_centre_deg=TARGET_ROLL_DEG.get(name, 0.0))]
            try:
                res = calibrate(dets, board, image_size=cam.size)
                diffs[name].append(projection_difference(cam, res)[0])
            except CalibrationError as e:
                failed[name] = f"failed (seed {seed}): {e}"
    rms = {name: float(np.sqrt(np.mean(np.square(d)))) if d else float("nan")
           for name, d in diffs.items()}
    out = {}
    for name, d in diffs.items():
        out[name] = failed.get(name) or (
            f"{rms[name]:.3f} ({min(d):.3f}-{max(d):.3f}), "
            f"{rms[name] / rms['marker_grid']:.2f} x")
    return out


def _table(title: str, rows: dict[str, dict[str, str]]) -> None:
    keys = list(next(iter(rows.values())))
    print(f"\n{title}\n")
    print("| case | " + " | ".join(keys) + " |", flush=True)
    print("|---|" + "---|" * len(keys))
    for case, row in rows.items():
        print(f"| {case} | " + " | ".join(row[k] for k in keys) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true", help="fewer views")
    parser.add_argument("--circles", action="store_true",
                        help="only the circle grid table (with --calibration: and that one)")
    parser.add_argument("--targets", default=",".join(TARGETS), metavar="NAME,...",
                        help="the calibration table's boards (the marker grid is always "
                             f"solved, as the reference); default {','.join(TARGETS)}")
    parser.add_argument("--calibration", action="store_true",
                        help="only the calibration table (with --circles: and that one)")
    args = parser.parse_args()
    views = 6 if args.quick else 20
    everything = not (args.circles or args.calibration)
    chess_rows, charuco_rows, april_rows, circle_rows = {}, {}, {}, {}
    for camera in ("webcam", "hd"):
        for k, condition in enumerate(CONDITIONS):
            case = f"{camera} {condition}"
            if everything:
                chess_rows[case] = chessboard(camera, condition, views, 101 + k)
                charuco_rows[case] = charuco(camera, condition, views, 201 + k)
                april_rows[case] = aprilgrid(camera, condition, views, 501 + k)
            if everything or args.circles:
                for board in (CIRCLES, ACIRCLES):
                    circle_rows[f"{board.board_type} {case}"] = circle_grid(
                        board, camera, CONDITIONS[condition], views, 601 + k)
    if everything:
        _table("Chessboard 9x6, whole-board views: frames found, RMS error px", chess_rows)
        _table("ChArUco 7x5, half the views partial", charuco_rows)
        _table("AprilGrid 6x6, half the views partial: tags, corner RMS px", april_rows)
    if circle_rows:
        _table("Circle grids (circles 9x6, acircles 4x11), whole-board views: frames found, "
               "centre RMS px", circle_rows)
    if everything:
        _table("Chessboard 9x6, squares of 4.5-6 px: frames found",
               {"webcam clean": small_squares("webcam", views, 401)})
    if everything or args.calibration:
        seeds = 2 if args.quick else 4
        names = [n for n in args.targets.split(",") if n]
        unknown = sorted(set(names) - set(TARGETS))
        if unknown:
            parser.error(f"--targets: unknown {', '.join(unknown)} (known: {', '.join(TARGETS)})")
        calib_rows = {camera: calibration(camera, 20, [301 + k + 10 * j for j in range(seeds)],
                                          names)
                      for k, camera in enumerate(("webcam", "hd"))}
        _table(f"Calibration, 20 realistic views, {seeds} seeds: projection difference px, "
               "RMS over the seeds (range), and its ratio to the marker grid's", calib_rows)

if __name__ == "__main__":
    main()
