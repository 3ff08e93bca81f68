"""Rig calibration against renderer truth and against OpenCV's stereo pipeline.

    python -m bench.rig             # rendered webcam and fisheye pairs, 3 seeds each, a
                                    # rendered trio, 2 seeds, and the real stereo photographs
                                    # (about 15 minutes on 2 busy cores)
    python -m bench.rig --quick     # one rendered webcam pair and the real photographs
    python -m bench.rig --parts trio,real   # only some parts

Rendered (:mod:`artcal_ros.synth.rig`'s ``stereo`` rig: 12 cm baseline, 0.38 deg between the
optical axes, the right camera a slightly different copy of the left; the default 19 x 9
board; 20 frames; clean light; fresh seeds). The same images go to both pipelines:

- artcal_ros: ``Detector`` per camera, ``calibrate_rig`` (corners).
- OpenCV: the default ``cv2.aruco.ArucoDetector`` corners, ``GridBoard.matchImagePoints``;
  each camera's intrinsics from ``cv2.calibrateCamera`` (``cv2.fisheye.calibrate``), then
  ``cv2.stereoCalibrate`` (``cv2.fisheye.stereoCalibrate``) with the intrinsics fixed, fed
  the markers both cameras found in a frame. OpenCV 4.12's ``fisheye.stereoCalibrate``
  fails on frames of different point counts, so each frame's points are padded to the
  largest count by repeating some of them.

Figures against the truth: baseline error (%), translation-vector error (mm), rotation error
(deg), and the rectified epipolar RMS (row difference after rectification; both
calibrations rectified by one rule, :func:`~artcal_ros.core.calibrate.rectify.rectify_pair`,
Bouguet's rotations as ``cv2.stereoRectify``, so only the calibrations differ) of the TRUE
images of every marker corner both cameras see (the calibration's own error, free of
detection noise), and of each pipeline's own detected corners (what a user measures); over
the corners inside both rectified images. The
per-camera projection difference of the rig solve (RMS over the image of the distance
between where the true and the estimated camera project the same rays) is compared with a
single-camera calibration of the same frames (``calibrate``, "alone").

The trio (``trio`` rig: cam0 cam1 cam2 15 cm apart, the outer two turned 35 deg outwards so
that they never see the board together) is solved by ``calibrate_rig`` alone, each pair
against the truth, cam0-cam2 chained through cam1.

The real photographs are :mod:`bench.rig_real`.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import cv2
import numpy as np

from artcal_ros import calibrate, calibrate_rig
from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.calibrate.rectify import epipolar_error, rectify_pair
from artcal_ros.core.camera import CameraModel
from artcal_ros.core.detect import Detector
from artcal_ros.synth import Camera, Photometry, render_view
from artcal_ros.synth.poses import marker_truth
from artcal_ros.synth.rig import Rig, rig_poses

BOARD = Board()
FRAMES = 20


def render_rig(rig: Rig, seed: int) -> tuple[dict[str, list[np.ndarray]],
                                               list[tuple[np.ndarray, np.ndarray]]]:
    """Per camera, ``FRAMES`` clean images of the same instants; the T_first_board poses."""
    rng = np.random.default_rng(seed)
    poses = rig_poses(BOARD, rig, FRAMES, rng)
    images: dict[str, list[np.ndarray]] = {n: [] for n in rig.names}
    for first_board in poses:
        for n in rig.names:
            r, t = rig.camera_pose(n, first_board)
            images[n].append(render_view(BOARD, rig.camera(n), r, t,
                                         photometry=Photometry.clean(), rng=rng).image)
    return images, poses


def true_pairs(rig: Rig, poses: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray,
                                                                               np.ndarray]:
    """(N, 2), (N, 2): the exact image of every marker corner both cameras see wholly."""
    a_all, b_all = [], []
    a, b = rig.names
    for first_board in poses:
        ca, _, ia, _ = marker_truth(BOARD, rig.camera(a), *rig.camera_pose(a, first_board))
        cb, _, ib, _ = marker_truth(BOARD, rig.camera(b), *rig.camera_pose(b, first_board))
        both = ia & ib
        a_all.append(ca[both].reshape(-1, 2))
        b_all.append(cb[both].reshape(-1, 2))
    return np.concatenate(a_all), np.concatenate(b_all)


def _rotation_error_deg(R_true: np.ndarray, R: np.ndarray) -> float:
    # from the skew part: cv2.Rodrigues rounds angles below 1e-5 rad to zero
    d = R_true.T @ np.asarray(R)
    s = 0.5 * np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]])
    return float(np.degrees(np.arctan2(np.linalg.norm(s), 0.5 * (np.trace(d) - 1.0))))


def _errors(rig: Rig, R: np.ndarray, t: np.ndarray,
            pair: tuple[str, str] | None = None) -> dict[str, float]:
    R_true, t_true = rig.extrinsics(*(pair or rig.names))
    base = float(np.linalg.norm(t_true))
    return {"baseline_pct": 100 * (float(np.linalg.norm(t)) - base) / base,
            "t_err_mm": 1e3 * float(np.linalg.norm(np.ravel(t) - t_true)),
            "rot_err_deg": _rotation_error_deg(R_true, R)}


def ours(rig: Rig, images: dict[str, list[np.ndarray]], truth: tuple[np.ndarray, np.ndarray],
         model: str) -> dict[str, Any]:
    """artcal_ros's detector and rig solve."""
    a, b = rig.names
    dets = {}
    for n in rig.names:
        detector = Detector(BOARD)
        dets[n] = [detector.detect(im, source=f"{n}{k}") for k, im in enumerate(images[n])]
    t0 = time.monotonic()
    res = calibrate_rig(dets, BOARD, image_sizes={n: rig.camera(n).size for n in rig.names},
                        model=model)
    solve_s = time.monotonic() - t0
    R, t = res.extrinsics[a, b]
    rect = res.rectification[a, b]
    ca, cb = res.cameras[a].camera, res.cameras[b].camera
    out = _errors(rig, R, t)
    out["epi_true_px"] = epipolar_error(ca, cb, rect, *truth)[0]
    out["epi_own_px"] = rect.epipolar_rms_px
    out["baseline_std_pct"] = 100 * res.pairs[a, b].baseline_std_m / res.pairs[a, b].baseline_m
    out["rot_std_deg"] = float(np.linalg.norm(res.pairs[a, b].rotation_std_deg))
    out["solve_s"] = solve_s
    proj = []
    for n in rig.names:
        single = calibrate(dets[n], BOARD, image_size=rig.camera(n).size, model=model)
        proj.append(f"{n} {projection_difference(rig.camera(n), res.cameras[n])[0]:.4f} px "
                    f"(alone {projection_difference(rig.camera(n), single)[0]:.4f})")
    out["projection"] = ", ".join(proj)
    return out


def _cv_points(images: list[np.ndarray]) -> list[dict[int, np.ndarray]]:
    detector = cv2.aruco.ArucoDetector(BOARD.dictionary, cv2.aruco.DetectorParameters())
    out = []
    for image in images:
        corners, ids, _ = detector.detectMarkers(image)
        found = {} if ids is None else {int(i): np.asarray(c, np.float64).reshape(4, 2)
                                        for i, c in zip(ids.ravel(), corners, strict=True)
                                        if BOARD.has_ids(np.array([i]))[0]}
        out.append(found)
    return out


def opencv(rig: Rig, images: dict[str, list[np.ndarray]],
           truth: tuple[np.ndarray, np.ndarray], model: str) -> dict[str, Any]:
    """OpenCV's pipeline: ArUco corners, calibrateCamera, stereoCalibrate, stereoRectify."""
    a, b = rig.names
    size = rig.camera(a).size
    found = {n: _cv_points(images[n]) for n in rig.names}
    intr = {}
    fisheye = model == "equidistant"
    for n in rig.names:
        obj = [BOARD.object_corners(np.array(sorted(f))).reshape(-1, 1, 3)
               for f in found[n] if len(f) >= 4]
        img = [np.array([f[i] for i in sorted(f)]).reshape(-1, 1, 2)
               for f in found[n] if len(f) >= 4]
        if fisheye:
            F = cv2.fisheye
            _, K, D, _, _ = F.calibrate(obj, img, size, None, None,
                                        flags=F.CALIB_RECOMPUTE_EXTRINSIC | F.CALIB_FIX_SKEW)
        else:
            _, K, D, _, _ = cv2.calibrateCamera([o.astype(np.float32) for o in obj],
                                                [i.astype(np.float32) for i in img], size,
                                                None, None)
        intr[n] = (K, D)
    obj, pa, pb = [], [], []
    for fa, fb in zip(found[a], found[b], strict=True):
        common = sorted(set(fa) & set(fb))
        if len(common) >= 4:
            obj.append(BOARD.object_corners(np.array(common)).reshape(-1, 1, 3))
            pa.append(np.array([fa[i] for i in common]).reshape(-1, 1, 2))
            pb.append(np.array([fb[i] for i in common]).reshape(-1, 1, 2))
    (K1, D1), (K2, D2) = intr[a], intr[b]
    if fisheye:
        F = cv2.fisheye
        # OpenCV 4.12's fisheye.stereoCalibrate fails on views of different point counts
        # (an assertion in its output allocation): every view is padded to the largest by
        # repeating its own points (a few points weigh twice; every point still counts)
        most = max(len(o) for o in obj)
        pad = [np.resize(np.arange(len(o)), most) for o in obj]
        out_s = F.stereoCalibrate([o[k] for o, k in zip(obj, pad, strict=True)],
                                  [p[k] for p, k in zip(pa, pad, strict=True)],
                                  [p[k] for p, k in zip(pb, pad, strict=True)],
                                  K1, D1, K2, D2, size, flags=F.CALIB_FIX_INTRINSIC)
        R, T = out_s[5], out_s[6]
    else:
        out_s = cv2.stereoCalibrate([o.astype(np.float32) for o in obj],
                                    [p.astype(np.float32) for p in pa],
                                    [p.astype(np.float32) for p in pb], K1, D1, K2, D2, size,
                                    flags=cv2.CALIB_FIX_INTRINSIC)
        R, T = out_s[5], out_s[6]
    n_dist = 4 if fisheye else 5
    cam1 = CameraModel(model, K1, np.ravel(D1)[:n_dist], size)
    cam2 = CameraModel(model, K2, np.ravel(D2)[:n_dist], size)
    out = _errors(rig, np.asarray(R), np.asarray(T).ravel())
    rect = rectify_pair(a, b, cam1, cam2, np.asarray(R), np.asarray(T).ravel(),
                        np.concatenate(pa).reshape(-1, 2), np.concatenate(pb).reshape(-1, 2))
    out["epi_true_px"] = epipolar_error(cam1, cam2, rect, *truth)[0]
    out["epi_own_px"] = rect.epipolar_rms_px
    out["frames"] = len(obj)
    return out


METRICS = (("baseline_pct", "baseline error %", "{:+.4f}"), ("t_err_mm", "t error mm", "{:.3f}"),
           ("rot_err_deg", "rotation error deg", "{:.4f}"),
           ("epi_true_px", "rectified epipolar RMS, true points px", "{:.4f}"),
           ("epi_own_px", "rectified epipolar RMS, own points px", "{:.4f}"))


def rendered(quick: bool) -> list[str]:
    """Markdown rows: per preset and seed, ours and OpenCV's figures and their ratio."""
    cases = [("webcam", "plumb_bob")] if quick else [("webcam", "plumb_bob"),
                                                      ("fisheye", "equidistant")]
    seeds = [2501] if quick else [2501, 2502, 2503]
    rows = ["| pair | seed | method | baseline error % | t error mm | rotation error deg | "
            "epipolar RMS, true points px | epipolar RMS, own points px | notes |",
            "|---|---|---|---|---|---|---|---|---|"]
    for preset, model in cases:
        rig = Rig.preset("stereo", Camera.preset(preset))
        for seed in seeds:
            t0 = time.monotonic()
            images, poses = render_rig(rig, seed)
            truth = true_pairs(rig, poses)
            render_s = time.monotonic() - t0
            o = ours(rig, images, truth, model)
            c = opencv(rig, images, truth, model)
            cells = [fmt.format(o[k]) for k, _, fmt in METRICS]
            rows.append(f"| {preset} | {seed} | artcal_ros | {' | '.join(cells)} | baseline "
                        f"1-sigma {o['baseline_std_pct']:.4f} %, rotation 1-sigma "
                        f"{o['rot_std_deg']:.4f} deg; projection difference "
                        f"{o['projection']}; solve {o['solve_s']:.1f} s |")
            cells = [fmt.format(c[k]) for k, _, fmt in METRICS]
            rows.append(f"| {preset} | {seed} | OpenCV | {' | '.join(cells)} | "
                        f"{c['frames']} shared frames; render {render_s:.0f} s |")
            ratio = [abs(c[k]) / max(abs(o[k]), 1e-12) for k, _, _ in METRICS]
            rows.append(f"| {preset} | {seed} | OpenCV / ours | "
                        + " | ".join(f"{r:.1f}x" for r in ratio) + " | |")
            print("\n".join(rows[-3:]), flush=True)
    return rows


def rendered_trio(seeds: list[int]) -> list[str]:
    """Markdown rows: the trio (outer cameras never see the board together), every pair
    against the truth; artcal_ros only (OpenCV has no rig solve to chain through cam1)."""
    rig = Rig.preset("trio", Camera.preset("webcam"))
    rows = ["| seed | pair | shared frames | baseline error % | t error mm | rotation error deg "
            "| baseline 1-sigma % | rotation 1-sigma deg | rectified epipolar RMS, own points "
            "px |", "|---|---|---|---|---|---|---|---|---|"]
    for seed in seeds:
        images, _ = render_rig(rig, seed)
        dets = {}
        for n in rig.names:
            detector = Detector(BOARD)
            dets[n] = [detector.detect(im, source=f"{n}{k}") for k, im in enumerate(images[n])]
        res = calibrate_rig(dets, BOARD, image_sizes={n: rig.camera(n).size for n in rig.names})
        for a, b in (("cam0", "cam1"), ("cam1", "cam2"), ("cam0", "cam2")):
            p = res.pairs[a, b]
            e = _errors(rig, p.R, p.t, (a, b))
            epi = res.rectification[a, b].epipolar_rms_px if (a, b) in res.rectification else ""
            rows.append(f"| {seed} | {a}-{b} | {p.shared_frames} | {e['baseline_pct']:+.4f} | "
                        f"{e['t_err_mm']:.3f} | {e['rot_err_deg']:.4f} | "
                        f"{100 * p.baseline_std_m / p.baseline_m:.4f} | "
                        f"{float(np.linalg.norm(p.rotation_std_deg)):.4f} | "
                        f"{epi if isinstance(epi, str) else f'{epi:.4f}'} |")
        print("\n".join(rows[-3:]), flush=True)
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one rendered webcam pair only")
    parser.add_argument("--parts", default="stereo,trio,real",
                        help="comma-separated: stereo (rendered pairs against OpenCV), trio "
                             "(rendered trio), real (the real photographs)")
    args = parser.parse_args(argv)
    parts = set(args.parts.split(","))
    if "stereo" in parts:
        print("## Rendered stereo pairs\n", flush=True)
        rows = rendered(args.quick)
        print("\n" + "\n".join(rows))
    if "trio" in parts and not args.quick:
        print("\n## Rendered trio, chained through cam1\n", flush=True)
        rows = rendered_trio([2601, 2602])
        print("\n" + "\n".join(rows))
    if "real" in parts:
        from bench.rig_real import real_pairs

        print("\n## Real stereo photographs (OpenCV's stereo chessboard samples)\n")
        print("\n".join(real_pairs()))


if __name__ == "__main__":
    main()
