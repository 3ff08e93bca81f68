"""Tone curve, edge shift and the board self-check against renderer truth.

    python -m bench.tone            # the figures in docs/benchmarks.md (~20 minutes on 2 cores)
    python -m bench.tone --quick    # fewer views, webcam and hd only (~5 minutes)

All images are fresh renders of the default 19 x 9 board (fixed seeds the unit tests do not
use); nothing is configured (``detector.gamma`` 0: the tone curve is estimated). Sections:

1. Clean light through four tone curves (linear, gamma 1.8, gamma 2.2, sRGB), ``webcam``:
   corner and centre RMS, the curve the detector used and its best fit.
2. Realistic frames per camera preset: each view its own defocus (disc radius 0.5 - 1.8 px),
   JPEG quality (70 - 95) and exposure (6 % - 150 % of full scale, log-uniform; above 125 %
   the paper clips). Corner RMS without (``DetectorConfig(edge_shift=False)``) and with the
   edge-shift compensation, and the centre RMS of the same markers; the same corners by
   exposure and by defocus.
3. Calibration from those 20 realistic views per preset: projection difference against the
   true camera (``bench.calibration``'s solve and metric), corners against centres.
4. Board self-check (``core/calibrate/board_check``, as ``artcal calibrate`` runs it, on the
   views its solve used): the board as configured, a print with 5 % more separation, and a
   page printed at 97 % (every length 0.97 x; not observable, see docs/tone.md: the bench
   shows that the intrinsics from such a page equal those from the true page).

Errors: markers found and fully inside the image with a shortest side of at least 20 px,
against the true image of the printed corners and centres.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.calibrate.board_check import check_board
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.detect import Detector, DetectorConfig
from artcal_ros.core.detections import Detections
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
from bench.calibration import PRESETS, solve_both

BOARD = Board()
CURVES: dict[str, Photometry] = {
    "linear": Photometry(gamma=1.0),
    "gamma 1.8": Photometry(gamma=1.8),
    "gamma 2.2": Photometry(gamma=2.2),
    "sRGB": Photometry(srgb=True),
}
MIN_SIDE_PX = 20.0
# (name, board as printed) of the self-check; the detector is always told BOARD
PRINTS = (("as configured", BOARD),
          ("separation +5 %", Board(marker_separation=1.05 * BOARD.marker_separation)),
          ("page at 97 %", Board(marker_length=0.97 * BOARD.marker_length,
                                 marker_separation=0.97 * BOARD.marker_separation)))


def realistic(rng: np.random.Generator) -> Photometry:
    """One view's light: ``bench.boards``' realistic light (40 % gradient, 30 % vignetting,
    a 4,000 e- well with 6 e- read noise) with defocus 0.5 - 1.8 px, JPEG 70 - 95 and an
    exposure of 0.06 - 1.5 (uniform in stops) drawn per view."""
    return Photometry(gradient=0.4, vignetting=0.3, full_well=4000.0, read_noise=6.0,
                      defocus_px=float(rng.uniform(0.5, 1.8)),
                      jpeg_quality=int(rng.integers(70, 96)),
                      exposure=float(np.exp(rng.uniform(np.log(0.06), np.log(1.5)))))


def errors(view: Any, det: Detections) -> tuple[np.ndarray, np.ndarray]:
    """Corner (M, 4) and centre (M,) errors, px, of the scored markers of one view."""
    k = det.ids - BOARD.first_id
    scored = view.inside[k] & (np.nan_to_num(view.side_px[k]) >= MIN_SIDE_PX)
    k = k[scored]
    corner = np.linalg.norm(det.corners_px[scored] - view.corners_px[k], axis=2)
    center = np.linalg.norm(det.centers_px[scored] - view.centers_px[k], axis=1)
    return corner, center


def rms(parts: list[np.ndarray]) -> float:
    a = np.concatenate([p.ravel() for p in parts]) if parts else np.zeros(0)
    return float(np.sqrt(np.mean(a * a))) if len(a) else float("nan")


def clean_curves(views: int, seed: int) -> list[dict[str, Any]]:
    """Section 1: one row per tone curve, one Detector per row (nothing configured)."""
    cam = Camera.preset("webcam")
    rows = []
    for k, (name, phot) in enumerate(CURVES.items()):
        rng = np.random.default_rng(seed + k)
        detector = Detector(BOARD)
        corner, center, first = [], [], float("nan")
        for i, (r, t) in enumerate(random_poses(BOARD, cam, views, rng)):
            view = render_view(BOARD, cam, r, t, photometry=phot, rng=rng)
            c, m = errors(view, detector.detect(view.image))
            corner.append(c)
            center.append(m)
            if i == 0:
                first = rms([c])
        tone = detector.tone
        row = {"curve": name, "views": views, "corners": rms(corner), "centers": rms(center),
               "first_frame_corners": first, "used": tone.curve.name,
               "fitted": (tone.fitted or tone.curve).name, "n": int(sum(len(c) for c in corner))}
        rows.append(row)
        print(f"{name:10s} corners {row['corners']:.4f} (first frame {first:.4f})  centres "
              f"{row['centers']:.4f}  used {row['used']}, best fit {row['fitted']}", flush=True)
    return rows


def realistic_set(preset: str, views: int, seed: int) -> dict[str, Any]:
    """Section 2 for one preset; keeps the detections for sections 3 and 4."""
    cam = Camera.preset(preset)
    rng = np.random.default_rng(seed)
    raw_det, comp_det = Detector(BOARD, DetectorConfig(edge_shift=False)), Detector(BOARD)
    out: dict[str, Any] = {"preset": preset, "raw": [], "comp": [], "views": [],
                           "light": [], "err_raw": [], "err_comp": [], "err_center": []}
    for r, t in random_poses(BOARD, cam, views, rng):
        phot = realistic(rng)
        view = render_view(BOARD, cam, r, t, photometry=phot, rng=rng)
        raw, comp = raw_det.detect(view.image), comp_det.detect(view.image)
        c_raw, _ = errors(view, raw)
        c_comp, m = errors(view, comp)
        out["raw"].append(raw)
        out["comp"].append(comp)
        out["light"].append((phot.exposure, phot.defocus_px, phot.jpeg_quality))
        out["err_raw"].append(c_raw)
        out["err_comp"].append(c_comp)
        out["err_center"].append(m)
    out["tone"] = comp_det.tone
    return out


def realistic_row(s: dict[str, Any]) -> dict[str, Any]:
    """Section 2's row of one preset, and its breakdown by exposure and defocus."""
    raw, comp, cen = rms(s["err_raw"]), rms(s["err_comp"]), rms(s["err_center"])
    light = np.array(s["light"], float)
    bands: dict[str, dict[str, float]] = {}
    for label, sel in (("exposure < 0.25", light[:, 0] < 0.25),
                       ("exposure 0.25 - 1", (light[:, 0] >= 0.25) & (light[:, 0] <= 1.0)),
                       ("exposure > 1", light[:, 0] > 1.0),
                       ("defocus < 1.1", light[:, 1] < 1.1),
                       ("defocus >= 1.1", light[:, 1] >= 1.1)):
        idx = np.flatnonzero(sel)
        bands[label] = {"views": len(idx),
                        "raw": rms([s["err_raw"][i] for i in idx]),
                        "comp": rms([s["err_comp"][i] for i in idx]),
                        "centers": rms([s["err_center"][i] for i in idx])}
    shifts = [d.edge_shift_px for d in s["comp"]]
    row = {"preset": s["preset"], "views": len(s["comp"]),
           "markers": int(sum(len(e) for e in s["err_comp"])), "raw": raw, "comp": comp,
           "centers": cen, "ratio": comp / cen, "tone_used": s["tone"].curve.name,
           "tone_fitted": (s["tone"].fitted or s["tone"].curve).name,
           "edge_shift_median": float(np.nanmedian(shifts)), "bands": bands}
    print(f"{row['preset']:8s} corners raw {raw:.4f} compensated {comp:.4f} centres {cen:.4f}"
          f" (ratio {row['ratio']:.2f}); tone {row['tone_used']} (best fit "
          f"{row['tone_fitted']}); median edge shift {row['edge_shift_median']:+.3f} px",
          flush=True)
    for label, b in bands.items():
        print(f"    {label:18s} {b['views']:2d} views  raw {b['raw']:.4f}  compensated "
              f"{b['comp']:.4f}  centres {b['centers']:.4f}", flush=True)
    return row


def realistic_calibration(s: dict[str, Any]) -> dict[str, Any]:
    """Section 3's row of one preset: corners (compensated and raw) against centres."""
    cam = Camera.preset(s["preset"])
    _, model, k3 = next(p for p in PRESETS if p[0] == s["preset"])
    both = solve_both(s["comp"], cam, model, k3)
    raw = solve_both(s["raw"], cam, model, k3, points=("corners",))
    row = {"preset": s["preset"], "views": len(s["comp"]),
           "centers": both["centers"].get("proj_rms", float("nan")),
           "corners": both["corners"].get("proj_rms", float("nan")),
           "corners_raw": raw["corners"].get("proj_rms", float("nan"))}
    print(f"{row['preset']:8s} projection difference RMS: centres {row['centers']:.4f}  "
          f"corners {row['corners']:.4f}  corners without the edge shift "
          f"{row['corners_raw']:.4f}", flush=True)
    return row


def board_checks(views: int, seed: int) -> list[dict[str, Any]]:
    """Section 4: the self-check on ``webcam`` views of each print, clean and realistic."""
    cam = Camera.preset("webcam")
    rows = []
    for k, (name, printed) in enumerate(PRINTS):
        for light in ("clean", "realistic"):
            rng = np.random.default_rng(seed + k)
            detector = Detector(BOARD)
            dets, tvecs = [], []
            for r, t in random_poses(printed, cam, views, rng):
                phot = Photometry.clean() if light == "clean" else realistic(rng)
                dets.append(detector.detect(render_view(printed, cam, r, t, photometry=phot,
                                                        rng=rng).image))
                tvecs.append(t)
            result = calibrate(dets, BOARD, image_size=cam.size)
            # a scaled page is the true page seen from further away: the distances scale
            distance = float(np.median([np.linalg.norm(result.tvecs[i])
                                        / np.linalg.norm(tvecs[v])
                                        for i, v in enumerate(result.views_used)]))
            check = check_board([dets[i] for i in result.views_used], BOARD, result.camera)
            true_ratio = printed.marker_length / (printed.marker_length
                                                  + printed.marker_separation)
            seen_ratio = BOARD.marker_length / (BOARD.marker_length + check.marker_separation)
            row = {"print": name, "light": light, "views": check.views,
                   "rendered_separation": printed.marker_separation,
                   "measured_separation": check.marker_separation,
                   "separation_error": check.marker_separation / printed.marker_separation - 1,
                   "ratio_error": seen_ratio / true_ratio - 1, "ratio_sigma": check.sigma,
                   "warning": check.warning,
                   "proj_rms": projection_difference(cam, result)[0],
                   "distance_ratio": distance}
            rows.append(row)
            print(f"{name:16s} {light:9s} separation {check.marker_separation:.6f} m "
                  f"(printed {printed.marker_separation:.6f}, {100 * row['separation_error']:+.2f}"
                  f" %); L/pitch {100 * row['ratio_error']:+.3f} % (1 sigma "
                  f"{100 * check.sigma:.3f} %); warning: {'yes' if check.warning else 'none'}; "
                  f"calibration {row['proj_rms']:.4f} px, distances x {distance:.4f}",
                  flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer views, webcam and hd")
    parser.add_argument("--work", default="/tmp/artcal_bench", help="scratch directory")
    parser.add_argument("--sections", default="1,2,3,4", help="which sections to run")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)
    sections = {s.strip() for s in args.sections.split(",")}
    results: dict[str, Any] = {}
    start = time.monotonic()
    if "1" in sections:
        views = 2 if args.quick else 6
        print(f"1. clean light, webcam, {views} views per curve, nothing configured")
        results["clean_curves"] = clean_curves(views, seed=7100)
    presets = [p[0] for p in (PRESETS[:2] if args.quick else PRESETS)]
    if sections & {"2", "3"}:
        views = 8 if args.quick else 20
        print(f"2. realistic frames, {views} views per preset: corner RMS px")
        sets = [realistic_set(p, views, seed=7200 + k) for k, p in enumerate(presets)]
        results["realistic"] = [realistic_row(s) for s in sets]
        if "3" in sections:
            print(f"3. calibration from the same {views} realistic views")
            results["calibration"] = [realistic_calibration(s) for s in sets]
    if "4" in sections:
        views = 6 if args.quick else 12
        print(f"4. board self-check, webcam, {views} views per print")
        results["board_check"] = board_checks(views, seed=7300)
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    (work / "tone_results.json").write_text(json.dumps(results, indent=2, default=str))
    print(f"results in {work / 'tone_results.json'} ({time.monotonic() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
