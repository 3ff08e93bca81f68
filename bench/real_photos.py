"""artcal_ros on real photographs with published references (OpenCV's ArUco tutorial images).

    python -m bench.real_photos              # tables as plain text (about 10 s)
    python -m bench.real_photos --markdown   # the same tables as Markdown

Data: ``test/data/real/opencv-aruco-tutorial`` (Apache-2.0, see its SOURCE.txt): four real
640x480 photos of a ChArUco board (5x7 squares of 40 mm, 20 mm DICT_6X6_250 markers, ids
0..16), one partly occluded ChArUco photo and one of six loose markers, with OpenCV's gold
marker corners (integers, +-1 px) and OpenCV's published calibration of the four photos.

What is measured:

1. Detection: ids found against the gold ids (recall; any other id is wrong), our corners
   against the gold corners, and against OpenCV's default ``ArucoDetector`` corners as a
   signed offset along each corner's diagonal (positive = ours further from the centre).
   The photos are not marker grids, so the detector gets a board holding every
   DICT_6X6_250 id (an id outside the photo would count as a wrong id) and the
   neighbour-position check is switched off (``neighbour_tolerance=inf``): a ChArUco
   board's markers do not sit where a grid board would put them. Every other check
   (polarity, code re-read after refinement, at most 2 wrong cells) is as in production.
2. Calibration of the four ChArUco photos with ``cv2.calibrateCamera`` (plumb_bob, flags 0)
   from marker corners or centres found by artcal_ros and by OpenCV's marker detector
   (default, SUBPIX and CONTOUR corner refinement), against the published calibration.
3. Marker corners against an independent reference: the board's chessboard saddle points
   (OpenCV's ChArUco corners less 0.5 px, because OpenCV 4.12's ``CharucoDetector``
   returns them shifted by +0.5 px in x and y, opencv/opencv#25539) give a
   calibration and poses; the printed marker corners projected with them are where the
   marker corners should be found, up to print and lens-model error.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, DetectorConfig

DATA = Path(__file__).resolve().parents[1] / "test" / "data" / "real" / "opencv-aruco-tutorial"
CALIB_IMAGES = ("img_00.jpg", "img_01.jpg", "img_02.jpg", "img_03.jpg")
# gold name -> file here (choriginal.jpg is byte-identical to img_01.jpg)
GOLD_PHOTOS = {"choriginal.jpg": "img_01.jpg",
               "chocclusion_original.jpg": "chocclusion_original.jpg",
               "singlemarkersoriginal.jpg": "singlemarkersoriginal.jpg"}
IMAGE_SIZE = (640, 480)
OPENCV_METHODS = {"default": cv2.aruco.CORNER_REFINE_NONE,
                  "subpix": cv2.aruco.CORNER_REFINE_SUBPIX,
                  "contour": cv2.aruco.CORNER_REFINE_CONTOUR}

Markers = tuple[np.ndarray, np.ndarray]  # ids (N,) int64, corners (N, 4, 2) float64 pixels


def load_image(name: str) -> np.ndarray:
    """(480, 640, 3) uint8 BGR photo ``name`` from the data folder."""
    img = cv2.imread(str(DATA / name), cv2.IMREAD_COLOR)
    if img is None:
        raise FileNotFoundError(f"{DATA / name} is missing or unreadable")
    return img


def load_gold() -> dict[str, dict[int, np.ndarray]]:
    """Gold corners per gold photo name: {id: (4, 2) float64 pixels, TL, TR, BR, BL}."""
    gold = json.loads((DATA / "gold_marker_corners.json").read_text())["images"]
    return {name: {int(k): np.asarray(v, dtype=np.float64)
                   for k, v in gold[name]["corners_xy_int"].items()} for name in GOLD_PHOTOS}


def load_reference() -> dict[str, float]:
    """The published calibration of img_00..03: fx, fy, cx, cy, rms (pixels)."""
    fs = cv2.FileStorage(str(DATA / "tutorial_camera_charuco.yml"), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    rms = fs.getNode("avg_reprojection_error").real()
    fs.release()
    return {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2], "rms": rms}


def tutorial_detector(estimate_lens: bool = True) -> Detector:
    """Our detector for loose DICT_6X6_250 markers (every id allowed, no neighbour check).

    ``estimate_lens=False`` fits every side as a straight line (no plumb-line lens).
    """
    # quiet zone: a ChArUco marker has 4 modules of white around it (square 2x marker)
    board = Board(cols=250, rows=1, marker_length=0.02, marker_separation=0.01,
                  dictionary_name="DICT_6X6_250", polarity="black")
    return Detector(board, DetectorConfig(neighbour_tolerance=float("inf"),
                                          estimate_lens=estimate_lens))


def opencv_markers(image: np.ndarray, method: str = "default") -> Markers:
    """OpenCV's ArucoDetector (default parameters but ``method`` corner refinement)."""
    p = cv2.aruco.DetectorParameters()
    p.cornerRefinementMethod = OPENCV_METHODS[method]
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    corners, ids, _ = cv2.aruco.ArucoDetector(dictionary, p).detectMarkers(image)
    if ids is None:
        return np.zeros(0, np.int64), np.zeros((0, 4, 2))
    return (np.asarray(ids, np.int64).ravel(),
            np.asarray(corners, np.float64).reshape(-1, 4, 2))


def ours_markers(detector: Detector, image: np.ndarray, camera: Any = None) -> Markers:
    """Our detector's ids and refined corners."""
    d = detector.detect(image, camera)
    return d.ids, d.corners_px


def diagonal_offsets(corners: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(N, 4) signed offsets, pixels, of ``corners`` from ``ref`` (both (N, 4, 2)) along
    each ref corner's direction from the ref quad's centre (positive = outward)."""
    u = ref - ref.mean(axis=1, keepdims=True)
    u /= np.linalg.norm(u, axis=2, keepdims=True)
    return np.asarray(((corners - ref) * u).sum(axis=2))


def matched(a: Markers, b: Markers) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ids in both, with the corners (K, 4, 2) of each set for them."""
    common = np.intersect1d(a[0], b[0])
    ia = np.array([int(np.flatnonzero(a[0] == i)[0]) for i in common], dtype=np.intp)
    ib = np.array([int(np.flatnonzero(b[0] == i)[0]) for i in common], dtype=np.intp)
    return common, a[1][ia], b[1][ib]


def detection_rows(detector: Detector) -> list[dict[str, Any]]:
    """Per gold photo: recall, wrong ids, distances to gold and offsets from OpenCV."""
    gold = load_gold()
    rows = []
    for gold_name, file in GOLD_PHOTOS.items():
        image = load_image(file)
        detector.reset_lens()  # the photos come from different cameras
        t0 = time.perf_counter()
        ours = ours_markers(detector, image)
        seconds = time.perf_counter() - t0
        g = gold[gold_name]
        gids = np.array(sorted(g), dtype=np.int64)
        gm = (gids, np.stack([g[int(i)] for i in gids]))
        ids, c_ours, c_gold = matched(ours, gm)
        dist = np.linalg.norm(c_ours - c_gold, axis=2)
        cv = opencv_markers(image)
        _, c_ours2, c_cv = matched(ours, cv)
        off = diagonal_offsets(c_ours2, c_cv)
        rows.append({"photo": gold_name, "gold": len(gids), "found": len(ids),
                     "wrong": sorted(set(ours[0].tolist()) - set(gids.tolist())),
                     "gold_mean_px": float(dist.mean()), "gold_max_px": float(dist.max()),
                     "gold_max_coord_px": float(np.abs(c_ours - c_gold).max()),
                     "cv_offset_mean_px": float(off.mean()), "cv_offset_std_px": float(off.std()),
                     "seconds": seconds})
    return rows


def charuco_board() -> cv2.aruco.CharucoBoard:
    """The tutorial's ChArUco board (5x7 squares, 0.04 / 0.02 m, DICT_6X6_250)."""
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_6X6_250)
    return cv2.aruco.CharucoBoard((5, 7), 0.04, 0.02, dictionary)


def marker_object_corners() -> np.ndarray:
    """(17, 4, 3) float64 metres: marker id k's corners TL, TR, BR, BL, y down the board.

    OpenCV lists them in float32 (0.06999999); the layout is on a 5 mm grid, so round.
    """
    obj = np.asarray(charuco_board().getObjPoints(), dtype=np.float64)
    return np.round(obj, 6)


def charuco_saddles(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Chessboard corner ids (M,) and saddle points (M, 2) in OpenCV's pixel convention.

    OpenCV 4.12's CharucoDetector adds 0.5 px to x and y after its cornerSubPix step
    (opencv/opencv#25539, fixed upstream in 2026); undo that. (Re-running cornerSubPix
    ourselves gives the same shift, but the result then depends on our window size.)
    """
    corners, ids, _, _ = cv2.aruco.CharucoDetector(charuco_board()).detectBoard(image)
    return (np.asarray(ids, np.int64).ravel(),
            np.asarray(corners, np.float64).reshape(-1, 2) - 0.5)


def diagonal_centers(corners: np.ndarray) -> np.ndarray:
    """(N, 2): intersection of each quad's diagonals (the image of the square's centre)."""
    h = np.concatenate([corners, np.ones((len(corners), 4, 1))], axis=2)
    c = np.cross(np.cross(h[:, 0], h[:, 2]), np.cross(h[:, 1], h[:, 3]))
    return np.asarray(c[:, :2] / c[:, 2:3])


def calibrate_points(obj: list[np.ndarray], img: list[np.ndarray]) -> dict[str, Any]:
    """cv2.calibrateCamera (plumb_bob, flags 0) on per-view (P, 3) / (P, 2) points, with
    the solver's 1-sigma of fx and fy (``fx_sd``, ``fy_sd``, px)."""
    rms, K, dist, rvecs, tvecs, sd, _, _ = cv2.calibrateCameraExtended(  # type: ignore[call-overload]
        [o.astype(np.float32) for o in obj], [i.astype(np.float32) for i in img],
        IMAGE_SIZE, None, None, flags=0)
    sd = np.asarray(sd, np.float64).ravel()
    return {"rms": float(rms), "fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2],
            "fx_sd": float(sd[0]), "fy_sd": float(sd[1]),
            "K": K, "dist": dist.ravel(), "rvecs": rvecs, "tvecs": tvecs,
            "points": int(sum(len(i) for i in img))}


def calibrate_markers(views: list[Markers], use: str) -> dict[str, Any]:
    """Calibrate from marker ``corners`` (4 per marker) or ``centers`` (1 per marker)."""
    table = marker_object_corners()
    obj, img = [], []
    for ids, corners in views:
        o = table[ids]
        if use == "centers":
            obj.append(o.mean(axis=1))
            img.append(diagonal_centers(corners))
        else:
            obj.append(o.reshape(-1, 3))
            img.append(corners.reshape(-1, 2))
    return calibrate_points(obj, img)


def calibrate_saddles(images: list[np.ndarray], fix_bias: bool = True) -> dict[str, Any]:
    """Calibration from the ChArUco saddle points (``fix_bias=False``: OpenCV's as returned)."""
    chess = np.asarray(charuco_board().getChessboardCorners(), dtype=np.float64)
    obj, img = [], []
    for image in images:
        if fix_bias:
            ids, pts = charuco_saddles(image)
        else:
            c, i, _, _ = cv2.aruco.CharucoDetector(charuco_board()).detectBoard(image)
            ids, pts = np.asarray(i, np.int64).ravel(), np.asarray(c, np.float64).reshape(-1, 2)
        obj.append(np.round(chess[ids], 6))
        img.append(pts)
    return calibrate_points(obj, img)


def marker_sets(detector: Detector, images: list[np.ndarray]) -> dict[str, list[Markers]]:
    """Marker corners of every calibration photo by each detector (ours pools its lens
    estimate over the photos, as it does over a camera's frames)."""
    detector.reset_lens()
    sets = {"artcal_ros": [ours_markers(detector, im) for im in images]}
    straight = tutorial_detector(estimate_lens=False)
    sets["artcal_ros, straight sides"] = [ours_markers(straight, im) for im in images]
    for method in OPENCV_METHODS:
        sets[f"OpenCV {method}"] = [opencv_markers(im, method) for im in images]
    return sets


def truth_offsets(views: list[Markers], saddle_cal: dict[str, Any]) -> dict[str, float]:
    """Marker corners against the printed corners projected with the saddle calibration."""
    table = marker_object_corners()
    offs, dists = [], []
    for v, (ids, corners) in enumerate(views):
        proj, _ = cv2.projectPoints(table[ids].reshape(-1, 3), saddle_cal["rvecs"][v],
                                    saddle_cal["tvecs"][v], saddle_cal["K"], saddle_cal["dist"])
        proj = proj.reshape(-1, 4, 2)
        offs.append(diagonal_offsets(corners, proj).ravel())
        dists.append(np.linalg.norm(corners - proj, axis=2).ravel())
    o, d = np.concatenate(offs), np.concatenate(dists)
    return {"offset_mean_px": float(o.mean()), "offset_std_px": float(o.std()),
            "dist_rms_px": float(np.sqrt((d ** 2).mean())), "dist_max_px": float(d.max())}


def rms_at(views: list[Markers], use: str, cal: dict[str, Any]) -> float:
    """Reprojection RMS, pixels, of marker points with the intrinsics of ``cal`` held fixed
    (one pose per view by solvePnP): corner quality without the weakly set K."""
    table = marker_object_corners()
    sq = []
    for ids, corners in views:
        o = table[ids]
        obj = o.mean(axis=1) if use == "centers" else o.reshape(-1, 3)
        img = diagonal_centers(corners) if use == "centers" else corners.reshape(-1, 2)
        _, rvec, tvec = cv2.solvePnP(obj, img, cal["K"], cal["dist"],
                                     flags=cv2.SOLVEPNP_ITERATIVE)
        proj, _ = cv2.projectPoints(obj, rvec, tvec, cal["K"], cal["dist"])
        sq.append(((proj.reshape(-1, 2) - img) ** 2).sum(axis=1))
    return float(np.sqrt(np.concatenate(sq).mean()))


def _table(head: list[str], rows: list[list[str]], markdown: bool) -> str:
    if markdown:
        lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        lines += ["| " + " | ".join(r) + " |" for r in rows]
        return "\n".join(lines)
    widths = [max(len(x) for x in col) for col in zip(head, *rows, strict=True)]
    return "\n".join("  ".join(x.ljust(w) for x, w in zip(r, widths, strict=True))
                     for r in [head, *rows])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--markdown", action="store_true", help="print Markdown tables")
    md = ap.parse_args(argv).markdown
    detector = tutorial_detector()
    det = detection_rows(detector)
    print("Detection (gold: OpenCV's integer corners, +-1 px; offset: ours minus OpenCV default "
          "along the diagonal, + = outward)\n")
    print(_table(["photo", "gold ids", "found", "wrong ids", "vs gold mean/max px",
                  "max per coord px", "offset vs OpenCV px", "seconds"],
                 [[r["photo"], str(r["gold"]), str(r["found"]), str(len(r["wrong"])),
                   f"{r['gold_mean_px']:.2f} / {r['gold_max_px']:.2f}",
                   f"{r['gold_max_coord_px']:.2f}",
                   f"{r['cv_offset_mean_px']:+.2f} +- {r['cv_offset_std_px']:.2f}",
                   f"{r['seconds']:.2f}"] for r in det], md))

    images = [load_image(n) for n in CALIB_IMAGES]
    ref = load_reference()
    sets = marker_sets(detector, images)
    saddle = calibrate_saddles(images)
    rows = [("published (OpenCV ChArUco corners)", "", ref),
            ("OpenCV 4.12 ChArUco corners (+0.5 px bug)", "",
             calibrate_saddles(images, fix_bias=False)),
            ("ChArUco saddles (the same less 0.5 px)", "", saddle)]
    cals: dict[str, dict[str, Any]] = {}
    for name, views in sets.items():
        for use in ("corners", "centers"):
            cals[f"{name} {use}"] = calibrate_markers(views, use)
            cals[f"{name} {use}"]["rms_fixed"] = rms_at(views, use, saddle)
            rows.append((f"{name} marker {use}", str(cals[f"{name} {use}"]["points"]),
                         cals[f"{name} {use}"]))
    print("\nCalibration of img_00..03 (cv2.calibrateCamera, plumb_bob, flags 0)\n")
    print(_table(["points", "n", "RMS px", "RMS at saddle K px", "fx", "fy", "cx", "cy",
                  "fx, fy vs published"],
                 [[name, n, f"{c['rms']:.3f}",
                   f"{c['rms_fixed']:.3f}" if "rms_fixed" in c else "",
                   f"{c['fx']:.1f}", f"{c['fy']:.1f}",
                   f"{c['cx']:.1f}", f"{c['cy']:.1f}",
                   f"{100 * (c['fx'] / ref['fx'] - 1):+.1f} %, "
                   f"{100 * (c['fy'] / ref['fy'] - 1):+.1f} %"]
                  for name, n, c in rows], md))
    print("\nMarker corners vs the printed corners projected with the saddle calibration "
          "(offset + = outward)\n")
    print(_table(["detector", "offset mean px", "offset std px", "distance RMS px", "max px"],
                 [[name, f"{t['offset_mean_px']:+.2f}", f"{t['offset_std_px']:.2f}",
                   f"{t['dist_rms_px']:.2f}", f"{t['dist_max_px']:.2f}"]
                  for name, t in ((n, truth_offsets(v, saddle)) for n, v in sets.items())],
                 md))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
