"""Calibration benchmarks against renderer truth.

    python -m bench.calibration --sections 1,2   # accuracy and uncertainty (~3 minutes)
    python -m bench.calibration                  # + the 2,000-frame bag (~45 minutes the
                                                 # first time; detections are cached)
    python -m bench.calibration --quick          # webcam and hd only, no bag
    python -m bench.calibration --seeds 8        # 20 realistic views over 8 seeds per
                                                 # preset: mean and worst (~30 minutes)

Sections (all on freshly rendered images, fixed seeds, compared in the same run):

1. Accuracy per camera preset, 20 random views, clean light: projection difference
   (RMS and max over the whole image of the distance between where the true and the
   estimated camera project the same rays) for ``points: centers`` and ``points:
   corners``, and for the plain OpenCV pipeline on the same images (default
   ``cv2.aruco.ArucoDetector`` corners, ``GridBoard.matchImagePoints``, default
   ``cv2.calibrateCamera``, or ``cv2.fisheye.calibrate`` for the fisheye).
2. Honesty of the reported uncertainty: Monte-Carlo spread of cx against the 1-sigma the
   solve reports (exact correspondences plus noise, so it runs in seconds).
3. A 2,000-frame rosbag2 recording (30 fps hand-held sweep): wall time of ``artcal
   calibrate --bag``, and its accuracy against a calibration from every frame.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.detect import Detector
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import CalibrationError
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
from artcal_ros.synth.poses import marker_truth

ROOT = Path(__file__).resolve().parents[1]
BOARD = Board()
PRESETS = (("webcam", "plumb_bob", False), ("hd", "plumb_bob", False),
           ("wide", "plumb_bob", True), ("fisheye", "equidistant", False))
TARGETS = {"webcam": 0.05, "hd": 0.1, "wide": 0.1, "fisheye": 0.2}


def render_set(cam: Camera, n: int, seed: int) -> list[np.ndarray]:
    """``n`` clean renderer images of random views."""
    rng = np.random.default_rng(seed)
    return [render_view(BOARD, cam, r, t, photometry=Photometry.clean(), rng=rng).image
            for r, t in random_poses(BOARD, cam, n, rng)]


def plain_opencv(images: list[np.ndarray], cam: Camera) -> Any:
    """The plain OpenCV pipeline: default ArUco corners + default calibration."""
    detector = cv2.aruco.ArucoDetector(BOARD.dictionary, cv2.aruco.DetectorParameters())
    cv_board = BOARD.to_cv_board()
    obj, img = [], []
    for image in images:
        corners, ids, _ = detector.detectMarkers(image)
        if ids is None or len(ids) < 4:
            continue
        o, i = cv_board.matchImagePoints(corners, ids)
        obj.append(o.astype(np.float32))
        img.append(i.astype(np.float32))
    try:
        if cam.model == "equidistant":
            F = cv2.fisheye
            _, K, D, _, _ = F.calibrate([o.reshape(-1, 1, 3).astype(np.float64) for o in obj],
                                        [i.reshape(-1, 1, 2).astype(np.float64) for i in img],
                                        cam.size, None, None,
                                        flags=F.CALIB_RECOMPUTE_EXTRINSIC | F.CALIB_FIX_SKEW)
        else:
            _, K, D, _, _ = cv2.calibrateCamera(obj, img, cam.size, None, None)
    except cv2.error as e:
        return f"failed: {str(e).strip().splitlines()[-1][:60]}"
    return Camera(cam.model, K, np.asarray(D).ravel()[:len(cam.dist)], cam.size)


def solve_both(dets: list[Detections], cam: Camera, model: str, k3: bool,
               points: tuple[str, ...] = ("centers", "corners")) -> dict[str, dict[str, Any]]:
    """points mode -> the calibration's projection difference against ``cam`` (RMS, max, px)
    and the solver's own figures, or {"error": why}."""
    out: dict[str, dict[str, Any]] = {}
    for mode in points:
        t0 = time.monotonic()
        try:
            r = calibrate(dets, BOARD, image_size=cam.size, model=model, points=mode, k3=k3)
        except CalibrationError as e:
            out[mode] = {"error": str(e)}
            continue
        rms, worst = projection_difference(cam, r)
        out[mode] = {"proj_rms": rms, "proj_max": worst, "reproj_std": r.reprojection_std_px,
                     "reproj_max": r.reprojection_max_px, "reproj_rms": r.reprojection_rms_px,
                     "holdout": r.holdout_rms_px,
                     "uncertainty_rms": r.projection_uncertainty_rms_px,
                     "views": len(r.views_used), "outliers": r.points_dropped,
                     "solve_s": time.monotonic() - t0}
    return out


def accuracy(quick: bool) -> list[dict[str, Any]]:
    """Section 1: one row per camera preset."""
    rows = []
    for k, (preset, model, k3) in enumerate(PRESETS[:2] if quick else PRESETS):
        cam = Camera.preset(preset)
        t0 = time.monotonic()
        images = render_set(cam, 20, seed=1000 + k)
        t_render = time.monotonic() - t0
        detector = Detector(BOARD)
        t0 = time.monotonic()
        dets = [detector.detect(im, source=f"{preset}{i}") for i, im in enumerate(images)]
        t_detect = (time.monotonic() - t0) / len(images)
        row: dict[str, Any] = {"preset": preset, "model": model + (" +k3" if k3 else ""),
                               "render_s": t_render, "detect_s_per_frame": t_detect,
                               "markers": int(sum(len(d) for d in dets))}
        row.update(solve_both(dets, cam, model, k3))
        base = plain_opencv(images, cam)
        if isinstance(base, str):
            row["opencv"] = {"error": base}
        else:
            rms, worst = projection_difference(cam, base)
            row["opencv"] = {"proj_rms": rms, "proj_max": worst}
        rows.append(row)
        print_row(row)
    return rows


def print_row(row: dict[str, Any]) -> None:
    def cell(d: dict[str, Any]) -> str:
        if "error" in d:
            return "fail"
        return f"{d['proj_rms']:.3f} / {d['proj_max']:.3f}"

    extra = ""
    if "proj_rms" in row.get("corners", {}) and "proj_rms" in row.get("centers", {}):
        extra = (f"  reproj std/max (corners) {row['corners']['reproj_std']:.3f}/"
                 f"{row['corners']['reproj_max']:.3f}  hold-out {row['corners']['holdout']:.3f}")
    print(f"{row['preset']:8s} {row['model']:16s} centers {cell(row['centers']):15s} "
          f"corners {cell(row['corners']):15s} opencv {cell(row['opencv']):15s}{extra}",
          flush=True)


def honesty(runs: int = 16) -> dict[str, float]:
    """Section 2: Monte-Carlo spread of cx vs the reported 1-sigma (webcam, 20 views)."""
    cam = Camera.preset("webcam")
    poses = random_poses(BOARD, cam, 20, np.random.default_rng(12))
    cx, std, proj, unc = [], [], [], []
    for k in range(runs):
        rng = np.random.default_rng(500 + k)
        dets = []
        for rvec, tvec in poses:
            corners, _, inside, _ = marker_truth(BOARD, cam, rvec, tvec)
            noisy = corners[inside] + rng.normal(0.0, 0.03, corners[inside].shape)
            dets.append(Detections(BOARD.ids[inside], noisy, noisy.mean(axis=1), cam.size))
        r = calibrate(dets, BOARD, image_size=cam.size, points="corners",
                      cross_validation_folds=0)
        cx.append(r.camera_matrix[0, 2] - cam.K[0, 2])
        std.append(r.std_devs["cx"])
        proj.append(projection_difference(cam, r)[0])
        unc.append(r.projection_uncertainty_rms_px)
    out = {"cx_spread": float(np.std(cx)), "cx_reported": float(np.mean(std)),
           "proj_rms_mean": float(np.mean(proj)), "uncertainty_mean": float(np.mean(unc))}
    print(f"uncertainty check ({runs} noise draws, 0.03 px): cx spread {out['cx_spread']:.4f} px"
          f" vs reported 1-sigma {out['cx_reported']:.4f} px; projection difference mean "
          f"{out['proj_rms_mean']:.4f} px vs reported projection uncertainty "
          f"{out['uncertainty_mean']:.4f} px", flush=True)
    return out


def _detect_chunk(args: tuple[str, int, int]) -> list[Detections]:
    """Detect markers in messages [start, stop) of a bag (one worker process)."""
    from artcal_ros.bag import BagReader
    from artcal_ros.core.images import image_to_numpy

    path, start, stop = args
    detector = Detector(BOARD)
    out = []
    with BagReader(path) as reader:
        for k, m in enumerate(reader.messages("/camera/image_raw")):
            if k >= stop:
                break
            if k >= start:
                out.append(detector.detect(image_to_numpy(m.decode()), source=str(k)))
    return out


def detect_all_frames(bag: Path, cache: Path, frames: int = 2000, workers: int = 2) -> list:
    """Every frame's detections (cached as a pickle: sigmas included)."""
    import pickle
    from concurrent.futures import ProcessPoolExecutor

    if cache.exists():
        return list(pickle.loads(cache.read_bytes()))
    chunks = [(str(bag), k, min(k + 100, frames)) for k in range(0, frames, 100)]
    dets: list[Detections] = []
    with ProcessPoolExecutor(workers) as pool:
        for part in pool.map(_detect_chunk, chunks):
            dets.extend(part)
            print(f"  detected {len(dets)}/{frames} frames", flush=True)
    cache.write_bytes(pickle.dumps(dets))
    return dets


def bag_benchmark(work: Path) -> dict[str, Any]:
    """Section 3: a 2,000-frame bag, the command's wall time and accuracy vs every frame."""
    from artcal_ros.cli import calibrate as command
    from artcal_ros.core.calibrate.solve import bundle_adjust, free_parameters
    from artcal_ros.core.calibrate.views import (
        lens_corrected_centers,
        view_points,
        view_problem,
    )
    from artcal_ros.core.camera_info import read_camera_info_yaml
    from artcal_ros.synth.dataset import write_dataset

    cam = Camera.preset("webcam")
    bag = work / "bag2000"
    if not (bag / "metadata.yaml").exists():
        print("rendering a 2,000-frame bag (once) ...", flush=True)
        write_dataset(BOARD, cam, bag, frames=2000, seed=2024, motion="smooth", bag=True,
                      rate_hz=30.0, overwrite=True)
    out: dict[str, Any] = {}
    yaml_path = work / "bag_camera.yaml"
    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    t0 = time.monotonic()
    code = command.run(parser.parse_args(["--bag", str(bag), "--output", str(yaml_path),
                                          "--quiet"]))
    out["command_wall_s"] = time.monotonic() - t0
    out["command_exit"] = code
    out["command_proj_rms"], out["command_proj_max"] = projection_difference(
        cam, read_camera_info_yaml(yaml_path))
    t0 = time.monotonic()
    dets = detect_all_frames(bag, work / "bag2000_detections.pkl")
    out["detect_all_s"] = time.monotonic() - t0
    t0 = time.monotonic()
    selected = calibrate(dets, BOARD, image_size=cam.size, max_views=40)
    out["select_and_solve_2000_s"] = time.monotonic() - t0
    out["selected_proj_rms"] = projection_difference(cam, selected)[0]
    # Every frame in one joint solve. OpenCV's solver builds a dense normal matrix over all
    # poses (12,000 unknowns here), so this uses the package's Schur-complement LM,
    # starting from the selected views' camera, with the same model, points and weights.
    t0 = time.monotonic()
    views = [view_points(d, BOARD, "centers", k) for k, d in enumerate(dets)]
    views = [v for v in views if view_problem(v, BOARD) is None]
    K0, D0 = selected.camera_matrix, selected.dist_coeffs
    views = [lens_corrected_centers(v, Camera("plumb_bob", K0, D0, cam.size)) for v in views]
    K, D, _, _ = bundle_adjust(views, K0, D0, "plumb_bob",
                               free=free_parameters("plumb_bob", False), weighted=True)
    out["all_frames_s"] = time.monotonic() - t0
    out["all_frames_views"] = len(views)
    out["all_frames_proj_rms"] = projection_difference(cam, Camera("plumb_bob", K, D,
                                                                   cam.size))[0]
    print(json.dumps(out, indent=2), flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="webcam and hd only, no bag")
    parser.add_argument("--work", default="/tmp/artcal_bench", help="scratch directory")
    parser.add_argument("--sections", default="1,2,3", help="which sections to run")
    parser.add_argument("--seeds", type=int, default=0,
                        help="only the seeds table: 20 realistic views, this many seeds")
    parser.add_argument("--presets", default="webcam,hd,wide,wide-k3",
                        help="rows of --seeds (bench/calibration_seeds.py)")
    parser.add_argument("--diagnose", action="store_true",
                        help="--seeds: radial corner bias and true corners plus noise")
    parser.add_argument("--per-frame", action="store_true",
                        help="--seeds: detect each view alone (artcal_ros.detect), not pooled")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    if args.seeds:
        from bench.calibration_seeds import seeds_table

        table = seeds_table(args.seeds, args.presets.split(","), args.diagnose,
                            work / "seeds", args.per_frame)
        (work / "calibration_seeds.json").write_text(json.dumps(table, indent=2))
        return 0
    sections = {s.strip() for s in args.sections.split(",")}
    results: dict[str, Any] = {}
    if "1" in sections:
        print("projection difference RMS / max, px (20 views, clean renderer images)")
        results["accuracy"] = accuracy(args.quick)
    if "2" in sections:
        results["honesty"] = honesty()
    if "3" in sections and not args.quick:
        results["bag"] = bag_benchmark(work)
    (work / "calibration_results.json").write_text(json.dumps(results, indent=2))
    print(f"results in {work / 'calibration_results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
