"""Detection benchmarks against renderer truth, with plain OpenCV in the same run.

    python -m bench.detection             # everything (the numbers in docs/benchmarks.md)
    python -m bench.detection --quick     # fewer views, a smaller false-positive set

All images are fresh renders (fixed seeds the unit tests do not use) of the
default 19 x 9 board through the ``webcam`` preset (640 x 480, strong barrel
distortion). Sections:

1. Accuracy and recall per photometric condition and board polarity, for
   artcal_ros and three OpenCV variants (``cv2.aruco.ArucoDetector`` with its
   default parameters, with ``CORNER_REFINE_SUBPIX`` and with
   ``CORNER_REFINE_CONTOUR``). Corner error: distance to the true image corner,
   over markers fully inside the image with a shortest side >= 20 px; centre
   error likewise (OpenCV's centre: the intersection of its quad's diagonals).
   Recall: share of markers fully inside with a side >= 15 px that are found.
2. Jitter: one pose rendered 30 times with independent noise; the standard
   deviation of every corner, RMS over corners.
3. False positives: wrong ids (an id whose true marker is not where it was
   reported) over renders of clutter without the board and over partial views.
4. Speed: median time per frame, ours against the default ArUco detector on the
   same frames (a ratio, since the machine's speed varies).
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector
from artcal_ros.core.detect.centers import diagonal_centers
from artcal_ros.synth import Camera, Photometry, random_poses, render_view

CAMERA = "webcam"
CONDITIONS: dict[str, Photometry] = {
    # read noise ~0.3 % of full scale, sharp
    "clean": Photometry.clean(),
    # defocus sigma ~0.7 px (a disc of radius 1.4 px), noise as clean
    "defocus": Photometry(defocus_px=1.4),
    # strong noise (~1.5 % of full scale, shot noise of a 1,500 e- well) and blur
    "noisy+blur": Photometry(defocus_px=1.8, full_well=1500.0, read_noise=12.0),
    # very dark and clipped exposures
    "dark": Photometry(exposure=0.06, full_well=1500.0, read_noise=6.0),
    "clipped": Photometry(exposure=2.5),
    # everything at once: uneven light, overexposure, defocus, motion blur, JPEG
    "harsh": Photometry.harsh(),
}
METHODS = ("artcal_ros", "opencv", "opencv+subpix", "opencv+contour")


def _opencv(board: Board, refine: int) -> Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]:
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = refine
    params.detectInvertedMarker = board.polarity != "black"
    det = cv2.aruco.ArucoDetector(board.dictionary, params)

    def run(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        corners, ids, _ = det.detectMarkers(image)
        if ids is None:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 4, 2))
        return np.asarray(ids).reshape(-1).astype(np.int64), \
            np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)

    return run


def detectors(board: Board) -> dict[str, Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]]:
    """name -> image -> (ids (N,), corners (N, 4, 2)) for every compared method."""
    ours = Detector(board)

    def run_ours(image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = ours.detect(image)
        return d.ids, d.corners_px

    return {"artcal_ros": run_ours,
            "opencv": _opencv(board, cv2.aruco.CORNER_REFINE_NONE),
            "opencv+subpix": _opencv(board, cv2.aruco.CORNER_REFINE_SUBPIX),
            "opencv+contour": _opencv(board, cv2.aruco.CORNER_REFINE_CONTOUR)}


@dataclass
class Tally:
    """Accumulated errors and counts of one method under one condition."""

    corner_err: list[np.ndarray] = field(default_factory=list)
    center_err: list[np.ndarray] = field(default_factory=list)
    wanted: int = 0
    found: int = 0
    wrong_ids: int = 0
    cut: int = 0

    def add(self, view: object, ids: np.ndarray, corners: np.ndarray, board: Board,
            centers: np.ndarray | None = None) -> None:
        """Score one frame's detections against the view's truth."""
        truth_corners = view.corners_px  # type: ignore[attr-defined]
        truth_centers = view.centers_px  # type: ignore[attr-defined]
        inside = view.inside  # type: ignore[attr-defined]
        side = view.side_px  # type: ignore[attr-defined]
        on_board = (ids >= board.first_id) & (ids <= int(board.ids[-1]))
        ids, corners = ids[on_board], corners[on_board]
        _, first = np.unique(ids, return_index=True)
        ids, corners = ids[first], corners[first]
        if centers is None:
            centers = diagonal_centers(corners, np.zeros((len(ids), 4)), None)[0]
        else:
            centers = centers[on_board][first]
        k = ids - board.first_id
        err = np.linalg.norm(corners - truth_corners[k], axis=2)
        # a wrong id: reported more than half a marker side from where that marker is
        off = np.linalg.norm(corners.mean(axis=1) - truth_corners[k].mean(axis=1), axis=1)
        bad = ~(off <= 0.5 * np.nan_to_num(side[k], nan=0.0))
        self.wrong_ids += int(bad.sum())
        # right id, but the marker runs off the image: its corners there are not corners
        self.cut += int((~inside[k] & ~bad).sum())
        good = inside[k] & (side[k] >= 20) & ~bad
        self.corner_err.append(err[good].ravel())
        self.center_err.append(np.linalg.norm(centers[good] - truth_centers[k][good], axis=1))
        want = inside & (side >= 15)
        self.wanted += int(want.sum())
        self.found += int((want & np.isin(np.arange(len(inside)) + board.first_id,
                                          ids[~bad])).sum())

    def row(self) -> dict[str, float]:
        """RMS / p95 / max corner error, RMS centre error (pixels), recall (%)."""
        e = np.concatenate(self.corner_err) if self.corner_err else np.zeros(0)
        c = np.concatenate(self.center_err) if self.center_err else np.zeros(0)
        if len(e) == 0:
            e = np.array([np.nan])
        if len(c) == 0:
            c = np.array([np.nan])
        return {"n": float(len(e)), "rms": float(np.sqrt(np.mean(e**2))),
                "p95": float(np.percentile(e, 95)), "max": float(np.max(e)),
                "center_rms": float(np.sqrt(np.mean(c**2))), "center_max": float(np.max(c)),
                "recall": 100.0 * self.found / max(self.wanted, 1)}


def accuracy(conditions: list[str], polarities: list[str], views: int, seed: int
             ) -> dict[tuple[str, str], dict[str, Tally]]:
    """Section 1: per (condition, polarity) and method."""
    cam = Camera.preset(CAMERA)
    out: dict[tuple[str, str], dict[str, Tally]] = {}
    for ci, cond in enumerate(conditions):
        for pi, pol in enumerate(polarities):
            board = Board(polarity=pol)
            dets = detectors(board)
            ours = Detector(board)
            tallies = {m: Tally() for m in METHODS}
            rng = np.random.default_rng(seed + 1000 * ci + 100 * pi)
            for rvec, tvec in random_poses(board, cam, views, rng, partial_fraction=0.3):
                view = render_view(board, cam, rvec, tvec, photometry=CONDITIONS[cond], rng=rng)
                for name, fn in dets.items():
                    if name == "artcal_ros":
                        d = ours.detect(view.image)
                        tallies[name].add(view, d.ids, d.corners_px, board, d.centers_px)
                    else:
                        ids, corners = fn(view.image)
                        tallies[name].add(view, ids, corners, board)
            out[(cond, pol)] = tallies
            r = tallies["artcal_ros"].row()
            print(f"  {cond:10s} {pol:6s} ours rms {r['rms']:.4f} recall {r['recall']:.1f}%",
                  flush=True)
    return out


def jitter(renders: int, seed: int) -> dict[str, float]:
    """Section 2: corner std over ``renders`` noisy renders of one pose (clean light)."""
    board = Board()
    cam = Camera.preset(CAMERA)
    rng = np.random.default_rng(seed)
    rvec, tvec = random_poses(board, cam, 1, rng, partial_fraction=0.0)[0]
    dets = detectors(board)
    stacks: dict[str, dict[int, list[np.ndarray]]] = {m: {} for m in METHODS}
    for _ in range(renders):
        view = render_view(board, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
        for name, fn in dets.items():
            ids, corners = fn(view.image)
            for i, c in zip(ids, corners, strict=True):
                stacks[name].setdefault(int(i), []).append(c)
    out = {}
    for name, per_id in stacks.items():
        stds = [np.std(np.stack(v), axis=0) for v in per_id.values() if len(v) == renders]
        out[name] = float(np.sqrt(np.mean(np.square(stds)))) if stds else float("nan")
    return out


def false_positives(clutter: int, partial: int, seed: int) -> dict[str, tuple[int, int, int]]:
    """Section 3: wrong ids in clutter renders and partial views, and cut markers, per method.

    A cut marker: one that runs off the image, reported with a corner on the
    image edge.
    """
    board = Board(polarity="mixed")
    cam = Camera.preset(CAMERA)
    dets = detectors(board)
    rng = np.random.default_rng(seed)
    wrong = {m: [0, 0, 0] for m in METHODS}
    # clutter: the board turned away behind the camera, so only the background shows
    for _ in range(clutter):
        rvec = rng.normal(0, 0.3, 3)
        view = render_view(board, cam, rvec, np.array([0.0, 0.0, -2.0]), rng=rng)
        for name, fn in dets.items():
            ids, _ = fn(view.image)
            wrong[name][0] += int(((ids >= board.first_id) & (ids <= board.ids[-1])).sum())
    for rvec, tvec in random_poses(board, cam, partial, rng, partial_fraction=1.0):
        view = render_view(board, cam, rvec, tvec, rng=rng)
        for name, fn in dets.items():
            ids, corners = fn(view.image)
            t = Tally()
            t.add(view, ids, corners, board)
            wrong[name][1] += t.wrong_ids
            wrong[name][2] += t.cut
    return {m: (v[0], v[1], v[2]) for m, v in wrong.items()}


def speed(frames: int, seed: int) -> tuple[float, float, float]:
    """Section 4: median ms per frame (ours, default ArUco) and markers per frame."""
    board = Board()
    cam = Camera.preset(CAMERA)
    rng = np.random.default_rng(seed)
    images = [render_view(board, cam, r, t, rng=rng).image
              for r, t in random_poses(board, cam, frames, rng)]
    ours = Detector(board)
    cv = cv2.aruco.ArucoDetector(board.dictionary, cv2.aruco.DetectorParameters())
    t_ours, t_cv, counts = [], [], []
    for img in images:
        t0 = time.perf_counter()
        counts.append(len(ours.detect(img)))
        t1 = time.perf_counter()
        cv.detectMarkers(img)
        t_cv.append(time.perf_counter() - t1)
        t_ours.append(t1 - t0)
    return 1e3 * float(np.median(t_ours)), 1e3 * float(np.median(t_cv)), float(np.mean(counts))


def main() -> None:
    """Run the sections and print markdown tables."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer views and renders")
    ap.add_argument("--views", type=int, default=None, help="views per condition and polarity")
    args = ap.parse_args()
    views = args.views or (4 if args.quick else 12)
    seed = 90210
    print(f"# Detection benchmark: {CAMERA} camera, 19x9 board, {views} views per cell\n",
          flush=True)
    conds = list(CONDITIONS)
    polarities = ["black", "white", "mixed"]
    cells = [(c, p) for c in conds for p in (polarities if c in ("clean", "defocus") else
                                                ["black"])]
    results: dict[tuple[str, str], dict[str, Tally]] = {}
    for cond, pol in cells:
        cell_seed = seed + 1000 * conds.index(cond) + 100 * polarities.index(pol)
        results.update(accuracy([cond], [pol], views, cell_seed))
    print("\n## Accuracy and recall (pixels; corners of markers >= 20 px, recall >= 15 px)\n")
    print("| condition | polarity | method | corners | RMS | p95 | max | centre RMS | "
          "centre max | recall % |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for (cond, pol), tallies in results.items():
        for name in METHODS:
            r = tallies[name].row()
            print(f"| {cond} | {pol} | {name} | {int(r['n'])} | {r['rms']:.4f} | "
                  f"{r['p95']:.4f} | {r['max']:.4f} | {r['center_rms']:.4f} | "
                  f"{r['center_max']:.4f} | {r['recall']:.1f} |")
    jit = jitter(10 if args.quick else 30, seed + 7)
    print("\n## Jitter (same pose, independent noise; corner std, RMS over corners, px)\n")
    print("| method | corner std |")
    print("|---|---|")
    for name, v in jit.items():
        print(f"| {name} | {v:.4f} |")
    n_fp = 30 if args.quick else 300
    fp = false_positives(n_fp, n_fp, seed + 11)
    print(f"\n## Wrong ids ({n_fp} clutter renders without the board, {n_fp} partial views; "
          "mixed-polarity board)\n")
    print("| method | wrong ids, clutter | wrong ids, partial views | "
          "cut markers, partial views |")
    print("|---|---|---|---|")
    for name, (a, b, c) in fp.items():
        print(f"| {name} | {a} | {b} | {c} |")
    ms_ours, ms_cv, markers = speed(10, seed + 13)
    print(f"\n## Speed ({markers:.0f} markers per 640x480 frame on average)\n")
    print(f"ours {ms_ours:.0f} ms, default ArucoDetector {ms_cv:.0f} ms per frame "
          f"(ratio {ms_ours / max(ms_cv, 1e-9):.1f})")


if __name__ == "__main__":
    main()
