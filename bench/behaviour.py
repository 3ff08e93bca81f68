"""A fingerprint of what the detector and the solve compute, to show a refactor changed nothing.

    python -m bench.behaviour save before.npz     # on the old code
    python -m bench.behaviour save after.npz      # on the new code
    python -m bench.behaviour compare before.npz after.npz

Fixed renders (seeds no test uses) of every board type through four camera presets, with
clean and harsh light, are detected by ``detect()`` and by one streamed ``Detector``; two
view sets are calibrated (marker corners and centres). Every array is saved as computed;
``compare`` reports each entry that differs in any bit, so "unchanged" means exactly equal.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from artcal_ros import Board, Detector, calibrate, detect, load_params
from artcal_ros.synth import Camera, Photometry, random_poses, render_view

ROOT = Path(__file__).resolve().parents[1]
BOARDS = {
    "marker_grid": ROOT / "config" / "calibrator.yaml",
    "charuco": ROOT / "config" / "boards" / "a4_charuco_5x7.yaml",
    "aprilgrid": ROOT / "config" / "boards" / "a0_aprilgrid_6x6.yaml",
    "chessboard": ROOT / "config" / "boards" / "a3_chessboard_8x6.yaml",
    "circles": ROOT / "config" / "boards" / "a4_circles_7x5.yaml",
}
PRESETS = ("webcam", "hd", "wide", "fisheye")
DET_FIELDS = ("ids", "corners_px", "centers_px", "corner_sigma_px", "center_sigma_px",
              "point_ids", "points_px", "point_sigma_px")


def _board(kind: str) -> Board:
    return Board.from_params(load_params(str(BOARDS[kind])))


def _put_detections(out: dict[str, np.ndarray], key: str, dets: object) -> None:
    for name in DET_FIELDS:
        out[f"{key}/{name}"] = np.asarray(getattr(dets, name))


def fingerprint(*, views_per_set: int = 3) -> dict[str, np.ndarray]:
    """Detections and calibrations of the fixed renders, keyed by what they are."""
    out: dict[str, np.ndarray] = {}
    for b, kind in enumerate(BOARDS):
        board = _board(kind)
        for c, preset in enumerate(PRESETS):
            cam = Camera.preset(preset)
            rng = np.random.default_rng(91_000 + 10 * b + c)
            poses = random_poses(board, cam, views_per_set, rng, partial_fraction=0.3)
            stream = Detector(board)
            for v, (rvec, tvec) in enumerate(poses):
                light = Photometry.harsh() if v % 2 else Photometry.clean()
                image = render_view(board, cam, rvec, tvec, photometry=light, rng=rng).image
                _put_detections(out, f"{kind}/{preset}/{v}/cold", detect(image, board))
                _put_detections(out, f"{kind}/{preset}/{v}/stream", stream.detect(image))
    board = _board("marker_grid")
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(91_999)
    views = [render_view(board, cam, r, t, photometry=Photometry.clean(), rng=rng).image
             for r, t in random_poses(board, cam, 14, rng, partial_fraction=0.2)]
    dets = [detect(image, board) for image in views]
    for points in ("corners", "centers"):
        result = calibrate(dets, board, image_size=cam.size, points=points)
        for name in ("camera_matrix", "dist_coeffs", "rvecs", "tvecs", "per_view_rms_px",
                     "residuals_px"):
            out[f"calibrate/{points}/{name}"] = np.asarray(getattr(result, name))
        out[f"calibrate/{points}/rms"] = np.array([result.reprojection_rms_px,
                                                   result.holdout_rms_px,
                                                   result.projection_uncertainty_rms_px])
    return out


def compare(before: dict[str, np.ndarray], after: dict[str, np.ndarray]) -> list[str]:
    """What differs between two fingerprints: one line per entry, empty when identical."""
    lines = [f"only before: {k}" for k in sorted(set(before) - set(after))]
    lines += [f"only after: {k}" for k in sorted(set(after) - set(before))]
    for key in sorted(set(before) & set(after)):
        a, b = before[key], after[key]
        if a.shape != b.shape or a.dtype != b.dtype:
            lines.append(f"{key}: shape/dtype {a.shape} {a.dtype} -> {b.shape} {b.dtype}")
        elif not np.array_equal(a, b, equal_nan=a.dtype.kind == "f"):
            worst = float(np.nanmax(np.abs(a.astype(float) - b.astype(float))))
            lines.append(f"{key}: differs (largest difference {worst:.3g})")
    return lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.behaviour", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    verbs = parser.add_subparsers(dest="verb", required=True)
    verbs.add_parser("save").add_argument("out")
    cmp = verbs.add_parser("compare")
    cmp.add_argument("before")
    cmp.add_argument("after")
    args = parser.parse_args(argv)
    if args.verb == "save":
        data = fingerprint()
        np.savez_compressed(args.out, **{k.replace("/", "|"): v for k, v in data.items()})
        print(f"{len(data)} arrays saved to {args.out}")
        return 0
    loaded = []
    for path in (args.before, args.after):
        with np.load(path) as npz:
            loaded.append({k.replace("|", "/"): npz[k] for k in npz.files})
    lines = compare(*loaded)
    print("\n".join(lines) if lines else f"identical: {len(loaded[0])} arrays")
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main())
