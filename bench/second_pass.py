"""Does a second detection pass with the first solve's camera pay?

    python -m bench.second_pass            # 4 presets x 2 photometries (~15 minutes, 1 core)
    python -m bench.second_pass --quick    # webcam only

For each camera preset (webcam and hd: plumb_bob; wide: plumb_bob with
``k_coefficients=3``; fisheye: equidistant), 20 random views rendered with fixed seeds,
clean and defocused (``Photometry(defocus_px=1.4)``):

1. first pass: a streamed :class:`Detector` (what ``artcal calibrate`` and the node do),
   then :func:`calibrate`;
2. second pass: the same images re-detected with
   ``detect(image, board, camera=result.camera)`` of the first result, then
   :func:`calibrate` again.

Reported per row and points mode: the projection difference (RMS / max over the whole image,
px) of both against the true camera, the change of the RMS, and the extra time of the
second pass (its detections plus its solve). Same images, same seeds, in one run.
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
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.detect import Detector, detect
from artcal_ros.core.errors import CalibrationError
from artcal_ros.synth import Camera, Photometry, random_poses, render_view

BOARD = Board()
# preset, model, k_coefficients (0: the model's default)
PRESETS = (("webcam", "plumb_bob", 0), ("hd", "plumb_bob", 0), ("wide", "plumb_bob", 3),
           ("fisheye", "equidistant", 0))
PHOTOMETRIES = {"clean": Photometry.clean(), "defocus 1.4": Photometry(defocus_px=1.4)}
VIEWS = 20


def render_set(cam: Camera, photometry: Photometry, seed: int) -> list[np.ndarray]:
    """``VIEWS`` renders of random views (fixed seed)."""
    rng = np.random.default_rng(seed)
    return [render_view(BOARD, cam, r, t, photometry=photometry, rng=rng).image
            for r, t in random_poses(BOARD, cam, VIEWS, rng)]


def one_row(preset: str, model: str, k: int, light: str, seed: int) -> dict[str, Any]:
    """Both passes on one image set; figures per points mode."""
    cam = Camera.preset(preset)
    images = render_set(cam, PHOTOMETRIES[light], seed)
    detector = Detector(BOARD)
    t0 = time.monotonic()
    first = [detector.detect(im, source=f"{preset}{i}") for i, im in enumerate(images)]
    t_first = time.monotonic() - t0
    row: dict[str, Any] = {"preset": preset, "model": model + (f" k={k}" if k else ""),
                           "light": light, "first_detect_s": t_first}
    for points in ("corners", "centers"):
        kwargs: dict[str, Any] = {"model": model, "points": points, "k_coefficients": k}
        cell: dict[str, Any] = {}
        try:
            r1 = calibrate(first, BOARD, image_size=cam.size, **kwargs)
        except CalibrationError as e:
            row[points] = {"error": f"first solve: {e}"}
            continue
        cell["first"] = projection_difference(cam, r1)
        camera = r1.camera
        t0 = time.monotonic()
        second = [detect(im, BOARD, camera=camera, source=f"{preset}{i}")
                  for i, im in enumerate(images)]
        t_detect = time.monotonic() - t0
        try:
            r2 = calibrate(second, BOARD, image_size=cam.size, **kwargs)
        except CalibrationError as e:
            row[points] = {**cell, "error": f"second solve: {e}"}
            continue
        cell["second"] = projection_difference(cam, r2)
        cell["extra_s"] = time.monotonic() - t0
        cell["extra_detect_s"] = t_detect
        cell["gain"] = 1.0 - cell["second"][0] / cell["first"][0]
        row[points] = cell
    print_row(row)
    return row


def print_row(row: dict[str, Any]) -> None:
    """One line per points mode."""
    for points in ("corners", "centers"):
        c = row[points]
        head = f"{row['preset']:8s} {row['model']:16s} {row['light']:12s} {points:8s}"
        if "gain" not in c:
            print(f"{head} {c.get('error', '')[:80]}", flush=True)
            continue
        print(f"{head} first {c['first'][0]:.3f} / {c['first'][1]:.3f}  second "
              f"{c['second'][0]:.3f} / {c['second'][1]:.3f}  RMS {100 * -c['gain']:+.0f}%  "
              f"extra {c['extra_s']:.1f} s (first detection {row['first_detect_s']:.1f} s)",
              flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="webcam only")
    parser.add_argument("--presets", default=",".join(p[0] for p in PRESETS),
                        help="comma-separated presets to run (default: all)")
    parser.add_argument("--out", default="/tmp/artcal_bench/second_pass.json",
                        help="where to write the figures as JSON")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)
    print(f"projection difference RMS / max, px ({VIEWS} views; RMS change of the second "
          "pass; extra time = its detection + its solve)")
    rows = []
    wanted = {"webcam"} if args.quick else set(args.presets.split(","))
    for k, (preset, model, kc) in enumerate(PRESETS):
        if preset not in wanted:
            continue
        for j, light in enumerate(PHOTOMETRIES):
            rows.append(one_row(preset, model, kc, light, seed=4000 + 10 * k + j))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(rows, indent=2))
    print(f"results in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
