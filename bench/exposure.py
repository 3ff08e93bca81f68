"""Exposure sweep (the paper's Figure 6): one scene, 16 exposures from very dark to clipped.

    python -m bench.exposure            # 3 poses (the figures in docs/benchmarks.md)
    python -m bench.exposure --quick    # 1 pose

Each pose of the default 19 x 9 board is rendered once in linear light through the
``webcam`` preset (default photometry: gentle light gradient and vignetting, clutter, read
and shot noise, plus a slightly soft lens: a defocus disc of 0.7 px) and then exposed 16
times, geometrically from 0.055 (the paper white at 4.4 % of full scale) to 13.2 (the
paper at 10.6 times full scale, the ink at 66 %), a factor of 240 like the paper's 0.25 -
60 ms; noise is drawn afresh per frame. The paper clips from exposure 1 / 0.8 = 1.25 on.

Per step, over the markers in view (fully inside the image, shortest side >= 15 px):
markers decoded, and the RMS error against the renderer's exact truth of the centres,
the raw corners (``DetectorConfig(edge_shift=False)``) and the compensated corners (the
default detector), each frame through a fresh detector (a new exposure is a new camera
setting); OpenCV's ``ArucoDetector`` with ``CORNER_REFINE_SUBPIX`` on the same frames
(its centre: the diagonals' crossing of its quad). Writes docs/exposure_sweep.png.
"""

from __future__ import annotations

import argparse
import itertools
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, DetectorConfig
from artcal_ros.core.detect.centers import diagonal_centers
from artcal_ros.synth import Camera, Photometry, random_poses
from artcal_ros.synth.photometry import sense_and_encode
from artcal_ros.synth.poses import marker_truth
from artcal_ros.synth.view import render_linear
from bench.drawing import dashed_line

STEPS = 16
EXPOSURE_MIN, EXPOSURE_MAX = 0.055, 13.2
SEED = 6060
# a slightly soft lens (disc radius, px): the white then spreads into the black border
DEFOCUS_PX = 0.7
METHODS = ("centres", "raw corners", "corners", "opencv centres", "opencv corners")
PLOT = Path(__file__).resolve().parent.parent / "docs" / "exposure_sweep.png"


def exposures(steps: int = STEPS) -> np.ndarray:
    """(steps,) exposures, geometric from :data:`EXPOSURE_MIN` to :data:`EXPOSURE_MAX`."""
    return np.geomspace(EXPOSURE_MIN, EXPOSURE_MAX, steps)


@dataclass
class Step:
    """Errors (pixels) and counts of one exposure step, pooled over the poses."""

    exposure: float
    wanted: int = 0
    decoded: int = 0
    decoded_cv: int = 0
    saturated: list[float] = field(default_factory=list)
    err: dict[str, list[np.ndarray]] = field(
        default_factory=lambda: {m: [] for m in METHODS})

    def rms(self, method: str) -> float:
        """RMS error of ``method`` (NaN when nothing was found), pixels."""
        e = np.concatenate(self.err[method]) if self.err[method] else np.zeros(0)
        return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


def _score(step: Step, key: str, ids: np.ndarray, points: np.ndarray, truth: np.ndarray,
           want: np.ndarray, first_id: int) -> int:
    """Add the errors of the wanted markers among ``ids``; returns how many were wanted."""
    k = ids - first_id
    ok = (k >= 0) & (k < len(want))
    k, points = k[ok], points[ok]
    good = want[k]
    e = np.linalg.norm(points[good] - truth[k[good]], axis=-1)
    step.err[key].append(e.ravel())
    return int(good.sum())


def run(camera: str, poses: int, seed: int = SEED, defocus_px: float = DEFOCUS_PX,
        only: list[int] | None = None) -> list[Step]:
    """The sweep: ``poses`` random whole-board poses x :data:`STEPS` exposures (``only``:
    these step indices)."""
    board = Board()
    cam = Camera.preset(camera)
    rng = np.random.default_rng(seed)
    phot = Photometry(defocus_px=defocus_px)
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    aruco = cv2.aruco.ArucoDetector(board.dictionary, params)
    steps = [Step(float(e)) for e in exposures()]
    for p, (rvec, tvec) in enumerate(random_poses(board, cam, poses, rng, partial_fraction=0.0)):
        lin = render_linear(board, cam, rvec, tvec, photometry=phot,
                            rng=np.random.default_rng(seed + 100 * p))
        corners, centers, inside, side = marker_truth(board, cam, rvec, tvec)
        want = inside & (side >= 15)
        for i, step in enumerate(steps):
            if only is not None and i not in only:
                continue
            noise = np.random.default_rng(seed + 100 * p + i + 1)
            image = sense_and_encode(lin, phot.with_(exposure=step.exposure), noise, "mono8")
            step.saturated.append(float(np.mean(image >= 255)))
            step.wanted += int(want.sum())
            comp = Detector(board).detect(image)
            raw = Detector(board, DetectorConfig(edge_shift=False)).detect(image)
            step.decoded += _score(step, "centres", comp.ids, comp.centers_px, centers, want,
                                   board.first_id)
            _score(step, "corners", comp.ids, comp.corners_px, corners, want, board.first_id)
            _score(step, "raw corners", raw.ids, raw.corners_px, corners, want,
                   board.first_id)
            cv_corners, cv_ids, _ = aruco.detectMarkers(image)
            if cv_ids is not None and len(cv_ids):
                ids = np.asarray(cv_ids, np.int64).reshape(-1)
                q = np.asarray(cv_corners, np.float64).reshape(-1, 4, 2)
                # an id OpenCV reports twice cannot be scored: keep the first
                _, first = np.unique(ids, return_index=True)
                ids, q = ids[first], q[first]
                c = diagonal_centers(q, np.zeros((len(ids), 4)), None)[0]
                step.decoded_cv += _score(step, "opencv centres", ids, c, centers, want,
                                          board.first_id)
                _score(step, "opencv corners", ids, q, corners, want, board.first_id)
        print(f"  pose {p + 1}/{poses}: {int(want.sum())} markers in view", flush=True)
    return steps


def table(steps: list[Step]) -> str:
    """The markdown table of the sweep."""
    nominal = min(steps, key=lambda s: abs(math.log(s.exposure)))
    lines = [f"| step | exposure | saturated % | decoded (of {nominal.wanted}) | opencv decoded "
             "| centres | raw corners | corners | corners - centres | opencv centres | "
             "opencv corners |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for i, s in enumerate(steps):
        diff = s.rms("corners") - s.rms("centres")
        saturated = f"{100 * np.mean(s.saturated):.0f}" if s.saturated else ""
        lines.append(
            f"| {i + 1} | {s.exposure:.3g} | {saturated} | {s.decoded} | "
            f"{s.decoded_cv} | {s.rms('centres'):.4f} | {s.rms('raw corners'):.4f} | "
            f"{s.rms('corners'):.4f} | {diff:+.4f} | {s.rms('opencv centres'):.4f} | "
            f"{s.rms('opencv corners'):.4f} |")
    return "\n".join(lines)


# --- plot -----------------------------------------------------------------------------------
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_BLACK = (0, 0, 0)
# BGR
_COLOURS = {"centres": (60, 150, 40), "raw corners": (40, 40, 210), "corners": (190, 100, 20),
            "opencv centres": (60, 150, 40), "opencv corners": (40, 40, 210)}


def plot(steps: list[Step], title: str) -> np.ndarray:
    """BGR figure: RMS error (log y) against exposure (log x), markers decoded below."""
    width, height, left, right, top = 1000, 760, 80, 230, 70
    err_h, gap, dec_h = 420, 60, 150
    canvas = np.full((height, width, 3), 255, np.uint8)
    plot_w = width - left - right
    ex = [s.exposure for s in steps]
    lx0, lx1 = math.log10(ex[0] / 1.2), math.log10(ex[-1] * 1.2)
    y_lo, y_hi = 0.005, 2.0

    def px(e: float) -> int:
        return round(left + (math.log10(e) - lx0) / (lx1 - lx0) * plot_w)

    def py(v: float) -> int:
        f = (math.log10(min(max(v, y_lo), y_hi)) - math.log10(y_lo)) / \
            (math.log10(y_hi) - math.log10(y_lo))
        return round(top + (1.0 - f) * err_h)

    for v in (0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0):
        y = py(v)
        cv2.line(canvas, (left, y), (left + plot_w, y), (225, 225, 225), 1)
        cv2.putText(canvas, f"{v:g}", (left - 50, y + 5), _FONT, 0.45, _BLACK, 1, cv2.LINE_AA)
    dec_top = top + err_h + gap
    for e in (0.1, 0.3, 1.0, 3.0, 10.0):
        x = px(e)
        for y0, y1 in ((top, top + err_h), (dec_top, dec_top + dec_h)):
            cv2.line(canvas, (x, y0), (x, y1), (225, 225, 225), 1)
        cv2.putText(canvas, f"{e:g}", (x - 12, dec_top + dec_h + 20), _FONT, 0.45, _BLACK, 1,
                    cv2.LINE_AA)
    x_sat = px(1.25)
    cv2.line(canvas, (x_sat, top), (x_sat, dec_top + dec_h), (150, 150, 150), 1)
    cv2.putText(canvas, "paper clips", (x_sat + 4, top + 16), _FONT, 0.45, (120, 120, 120), 1,
                cv2.LINE_AA)
    cv2.rectangle(canvas, (left, top), (left + plot_w, top + err_h), _BLACK, 1)
    legend_y = top + 10
    for m in METHODS:
        colour = _COLOURS[m]
        pts = [(px(s.exposure), py(s.rms(m))) for s in steps if np.isfinite(s.rms(m))]
        for a, b in itertools.pairwise(pts):
            if m.startswith("opencv"):
                dashed_line(canvas, a, b, colour)
            else:
                cv2.line(canvas, a, b, colour, 2, cv2.LINE_AA)
        for q in pts:
            cv2.circle(canvas, q, 4 if not m.startswith("opencv") else 2, colour, -1,
                       cv2.LINE_AA)
        lx = left + plot_w + 15
        if m.startswith("opencv"):
            dashed_line(canvas, (lx, legend_y), (lx + 40, legend_y), colour)
        else:
            cv2.line(canvas, (lx, legend_y), (lx + 40, legend_y), colour, 2, cv2.LINE_AA)
        label = {"corners": "corners, compensated"}.get(m, m)
        cv2.putText(canvas, label, (lx + 48, legend_y + 5), _FONT, 0.45, _BLACK, 1,
                    cv2.LINE_AA)
        legend_y += 26
    # markers decoded, share of those in view
    cv2.rectangle(canvas, (left, dec_top), (left + plot_w, dec_top + dec_h), _BLACK, 1)
    for v in (0, 50, 100):
        y = round(dec_top + (1 - v / 100) * dec_h)
        cv2.line(canvas, (left, y), (left + plot_w, y), (225, 225, 225), 1)
        cv2.putText(canvas, f"{v}%", (left - 50, y + 5), _FONT, 0.45, _BLACK, 1, cv2.LINE_AA)
    for key, colour, dashed in (("decoded", (190, 100, 20), False),
                                ("decoded_cv", (120, 120, 120), True)):
        pts = [(px(s.exposure),
                round(dec_top + (1 - getattr(s, key) / max(s.wanted, 1)) * dec_h))
               for s in steps]
        for a, b in itertools.pairwise(pts):
            if dashed:
                dashed_line(canvas, a, b, colour)
            else:
                cv2.line(canvas, a, b, colour, 2, cv2.LINE_AA)
        for q in pts:
            cv2.circle(canvas, q, 3, colour, -1, cv2.LINE_AA)
    lx, ly = left + plot_w + 15, dec_top + 20
    cv2.line(canvas, (lx, ly), (lx + 40, ly), (190, 100, 20), 2, cv2.LINE_AA)
    cv2.putText(canvas, "artcal_ros", (lx + 48, ly + 5), _FONT, 0.45, _BLACK, 1, cv2.LINE_AA)
    dashed_line(canvas, (lx, ly + 26), (lx + 40, ly + 26), (120, 120, 120))
    cv2.putText(canvas, "opencv", (lx + 48, ly + 31), _FONT, 0.45, _BLACK, 1, cv2.LINE_AA)
    cv2.putText(canvas, title, (left, 28), _FONT, 0.6, _BLACK, 1, cv2.LINE_AA)
    cv2.putText(canvas, "RMS error against truth, px (log); dashed: OpenCV ArucoDetector + "
                "subpix", (left, 54), _FONT, 0.45, _BLACK, 1, cv2.LINE_AA)
    cv2.putText(canvas, "markers decoded, % of those in view", (left, dec_top - 10), _FONT,
                0.45, _BLACK, 1, cv2.LINE_AA)
    cv2.putText(canvas, "exposure (1: paper at 80 % of full scale), log", (left + 150,
                height - 12), _FONT, 0.5, _BLACK, 1, cv2.LINE_AA)
    return canvas


def main(argv: list[str] | None = None) -> None:
    """Run the sweep, print the table, write the plot."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="one pose instead of three")
    ap.add_argument("--camera", default="webcam", help="renderer preset (webcam, hd, ...)")
    ap.add_argument("--poses", type=int, default=None, help="poses (default 3, --quick 1)")
    ap.add_argument("--plot", type=Path, default=PLOT, help="PNG to write")
    args = ap.parse_args(argv)
    poses = args.poses or (1 if args.quick else 3)
    print(f"# Exposure sweep: {args.camera} camera, 19x9 board, {poses} pose(s), "
          f"{STEPS} exposures {EXPOSURE_MIN:g} - {EXPOSURE_MAX:g}\n", flush=True)
    steps = run(args.camera, poses)
    print()
    print(table(steps))
    decoded = [s for s in steps if s.decoded]
    met = [s for s in decoded if s.rms("corners") - s.rms("centres") <= 0.05]
    nominal = min(steps, key=lambda s: abs(math.log(s.exposure)))
    print(f"\ncorners within 0.05 px of the centres: {len(met)} of {len(decoded)} steps with "
          f"markers; markers decoded at {len(decoded)} of {len(steps)} steps; brightest two: "
          f"{steps[-2].decoded}, {steps[-1].decoded} (half of nominal: "
          f"{nominal.decoded / 2:.0f})")
    args.plot.parent.mkdir(parents=True, exist_ok=True)
    title = f"Exposure sweep, {args.camera}, {poses} pose(s) x {STEPS} exposures"
    cv2.imwrite(str(args.plot), plot(steps, title))
    print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
