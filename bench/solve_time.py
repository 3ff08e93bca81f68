"""Solve time against the number of views, per points mode: does ``max_views`` keep
``~/calibrate`` under 5 s?

    python -m bench.solve_time            # webcam and hd, 10..200 views (~45 min, 2 cores)
    python -m bench.solve_time --quick    # webcam, 10/40/80 views, one run each (~3 min)

For the ``webcam`` and ``hd`` presets, N views (N = 10, 20, 40, 80, 120, 200) of the default
board are solved by :func:`artcal_ros.core.calibrate.calibrate` with ``points`` = corners and
centers, once with ``max_views = N`` (every view solved) and once with the default
``max_views`` of config/calibrator.yaml (40: the most diverse 40 are chosen). Then the
session path the node runs for ``~/calibrate`` (:func:`run_solve`: solve on a thread, write
the YAML) with 200 collected views, at ``max_views`` from 20 up to the default, timed and
scored against the true camera over 8 view sets, and a cProfile breakdown (CPU seconds) of
the slowest default case by CPU time.

The detections are the renderer's exact marker images (:func:`marker_truth`) plus Gaussian
corner noise (0.03 px, the detector's jitter on clean images), with centres from the noisy
corners, instead of rendered and detected images: the solve sees only the point lists, so
its time does not depend on how the points were found (and detection alone costs 0.6 to
2.6 s a frame on these cores: 400 rendered views would add half an hour and change no
figure). Each point carries a 1-sigma, as the detector's do, so the solve takes its
weighted path (the point-weighted LM refinement after OpenCV's solve) as on real
detections; without sigmas it would time a cheaper path than the node runs.

Times are wall seconds, median of ``--repeats`` runs (a case whose first run takes longer
than ``--repeat-cap`` seconds runs once: its noise is small beside its size), with the
process CPU seconds beside them: on shared cores the wall time includes waiting for a core.
View sets are nested (the first N of 200 fixed-seed views), so the curves differ only by N.
"""

from __future__ import annotations

import argparse
import cProfile
import functools
import itertools
import json
import math
import pstats
import statistics
import sys
import tempfile
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.calibrate.solve_run import SolveWorker, run_solve
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import CalibrationError
from artcal_ros.core.live.coverage import Readiness
from artcal_ros.core.params import load_params
from artcal_ros.synth import PRESETS as ALL_PRESETS
from artcal_ros.synth import Camera, marker_truth, random_poses
from bench.drawing import dashed_line

ROOT = Path(__file__).resolve().parents[1]
PARAMS_FILE = ROOT / "config" / "calibrator.yaml"
BOARD = Board()
PRESETS = ("webcam", "hd")
POINTS = ("corners", "centers")
VIEW_COUNTS = (10, 20, 40, 80, 120, 200)
QUICK_VIEW_COUNTS = (10, 40, 80)
SESSION_VIEWS = 200  # views collected before ~/calibrate in the session rows
SWEEP_MAX_VIEWS = (20, 25, 30, 35)  # max_views tried on the session path (and the default)
SESSION_SETS = 8  # view sets per session row: which views are chosen moves the accuracy a lot
NOISE_PX = 0.03  # corner jitter per axis, pixels (the detector's on clean images)
BUDGET_S = 5.0  # what ~/calibrate should cost at most
SEED = 5100  # not used by the unit tests


def default_max_views() -> int:
    """``max_views`` of config/calibrator.yaml: what the node and the CLI solve with."""
    return int(load_params(PARAMS_FILE)["max_views"])


def preset_seed(preset: str, seed: int) -> int:
    """The view-set seed of a preset: ``seed`` + 10 x its place among the synth presets
    (so a preset gets the same views whichever presets run with it)."""
    return seed + 10 * ALL_PRESETS.index(preset)


def diagonal_centers(corners: np.ndarray) -> np.ndarray:
    """Marker centres as the intersection of the quad's diagonals: (M, 4, 2) -> (M, 2) px."""
    h = np.concatenate([corners, np.ones((*corners.shape[:2], 1))], axis=2)
    c = np.cross(np.cross(h[:, 0], h[:, 2]), np.cross(h[:, 1], h[:, 3]))
    return np.asarray(c[:, :2] / c[:, 2:3])


def truth_views(preset: str, n: int, seed: int,
                noise_px: float = NOISE_PX) -> tuple[Camera, list[Detections]]:
    """``n`` random views of the default board as a detector would report them.

    Args:
        preset: a :class:`Camera` preset (webcam, hd, wide, fisheye).
        n: number of views.
        seed: of the poses and of the noise (two streams, so a set's noise does not
            depend on how many poses were drawn before it).
        noise_px: 1-sigma Gaussian noise of each corner coordinate, pixels.

    Returns:
        (the true camera, one Detections per view: the markers fully inside the image,
        corners with noise, centres from the noisy corners, corner sigma ``noise_px``
        and centre sigma ``noise_px / 2``, the spread of the mean of four corners).
    """
    cam = Camera.preset(preset)
    rng = np.random.default_rng(seed)
    poses = random_poses(BOARD, cam, n, rng)
    # Separate stream: nested sets stay nested. (It is the next seed's pose stream, drawn
    # here as Gaussian noise, there as uniform pose parameters: no shared structure.)
    noise = np.random.default_rng(seed + 1)
    dets = []
    for k, (rvec, tvec) in enumerate(poses):
        corners, _, inside, _ = marker_truth(BOARD, cam, rvec, tvec)
        noisy = corners[inside] + noise.normal(0.0, noise_px, corners[inside].shape)
        m = int(inside.sum())
        dets.append(Detections(BOARD.ids[inside], noisy, diagonal_centers(noisy), cam.size,
                               np.full((m, 4), noise_px), np.full(m, 0.5 * noise_px),
                               source=f"{preset}{k}"))
    return cam, dets


def _timed(fn: Callable[[], Any], repeats: int, cap_s: float) -> tuple[list[float], list[float],
                                                                        Any]:
    """Run ``fn`` up to ``repeats`` times (once if the first run exceeds ``cap_s`` s).

    Returns:
        (wall seconds of each run, process CPU seconds of each run, the last run's value).
    """
    walls: list[float] = []
    cpus: list[float] = []
    value: Any = None
    for _ in range(max(1, repeats)):
        c0, t0 = time.process_time(), time.perf_counter()
        value = fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
        if walls[0] > cap_s:
            break
    return walls, cpus, value


def _score(cam: Camera, result: Any) -> tuple[float, float]:
    """Projection difference (RMS, max) px of a result against the true camera."""
    return projection_difference(cam, result)


def solve_time_rows(presets: Sequence[str] = PRESETS, counts: Sequence[int] = VIEW_COUNTS, *,
                    repeats: int = 3, repeat_cap_s: float = 30.0, seed: int = SEED,
                    max_views: int | None = None,
                    log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Time :func:`calibrate` per preset, points mode, view count and ``max_views`` setting.

    Args:
        presets: camera presets.
        counts: view counts N; the views of N are the first N of max(counts).
        repeats: runs per case (the median is reported).
        repeat_cap_s: a case whose first run takes longer runs once, seconds.
        seed: of the view sets (see :func:`preset_seed`).
        max_views: the default setting (None: config/calibrator.yaml's).
        log: called with one line per finished case.

    Returns:
        One row per (preset, points, N, setting): ``setting`` is ``all`` (max_views = N) or
        ``default``; ``wall_s``/``cpu_s`` medians, seconds; ``walls_s`` every run;
        ``views_used``; ``rms_px``/``max_px`` projection difference against the truth;
        ``same_as_all``: True where N <= the default, so the two settings are one solve
        (timed once, reported for both); ``error`` instead of figures if the solve failed.
    """
    default = default_max_views() if max_views is None else int(max_views)
    rows: list[dict[str, Any]] = []
    for preset in presets:
        cam, every = truth_views(preset, max(counts), preset_seed(preset, seed))
        for points in POINTS:
            for n in counts:
                dets = every[:n]
                all_row: dict[str, Any] | None = None
                for setting, mv in (("all", n), ("default", default)):
                    head = {"preset": preset, "points": points, "views": n,
                            "setting": setting, "max_views": mv}
                    if all_row is not None and n <= default:
                        # With N <= max_views nothing is selected: the very same solve.
                        rows.append({**all_row, **head, "same_as_all": True})
                        continue
                    try:
                        walls, cpus, result = _timed(
                            functools.partial(calibrate, dets, BOARD, image_size=cam.size,
                                              points=points, max_views=mv),
                            repeats, repeat_cap_s)
                    except CalibrationError as e:
                        rows.append({**head, "error": str(e)})
                        log(f"{preset:6s} {points:7s} N={n:3d} {setting:7s} failed: {e}")
                        continue
                    rms, worst = _score(cam, result)
                    row = {**head, "wall_s": statistics.median(walls),
                           "cpu_s": statistics.median(cpus), "walls_s": walls,
                           "views_used": len(result.views_used), "rms_px": rms,
                           "max_px": worst, "same_as_all": False}
                    rows.append(row)
                    if setting == "all":
                        all_row = row
                    log(f"{preset:6s} {points:7s} N={n:3d} max_views={mv:3d}: "
                        f"{row['wall_s']:6.2f} s wall ({row['cpu_s']:6.2f} s CPU, "
                        f"{len(walls)} run(s)), {row['views_used']} views used, "
                        f"{rms:.4f} px RMS from the truth")
    return rows


def session_rows(presets: Sequence[str] = PRESETS, max_views: Sequence[int] = SWEEP_MAX_VIEWS,
                 *, views: int = SESSION_VIEWS,
                 seeds: Sequence[int] = tuple(SEED + k for k in range(SESSION_SETS)),
                 points: Sequence[str] = POINTS, output_dir: Path | None = None,
                 log: Callable[[str], None] = print) -> list[dict[str, Any]]:
    """Time the node's ``~/calibrate`` path (:func:`run_solve`) and score its result.

    The parameters are config/calibrator.yaml's with ``max_views`` (and ``points``) set and
    the YAML written to a temporary directory. One run per view set; several view sets
    (``seeds``) give the median time and accuracy.

    Args:
        presets: camera presets.
        max_views: the ``max_views`` values tried.
        views: views collected per set.
        seeds: one view set each (see :func:`preset_seed`; the first is the set
            :func:`solve_time_rows` solves at N = ``views`` with the same seed).
        points: points modes.
        output_dir: where the YAML goes (default: a temporary directory).
        log: called with one line per finished case.

    Returns:
        One row per (preset, points, max_views): ``wall_s``/``cpu_s`` medians over the
        sets, ``walls_s`` every run, ``rms_px``/``max_px`` medians of the projection
        difference against the truth, ``rms_sets_px`` the RMS of each set in ``seeds``
        order (NaN where it failed), ``sets`` the number of sets solved; ``error`` where
        a solve failed.
    """
    with tempfile.TemporaryDirectory(prefix="artcal_solve_time_") as tmp:
        out = Path(output_dir) if output_dir is not None else Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        sets = {(preset, s): truth_views(preset, views, preset_seed(preset, s))
                for preset in presets for s in seeds}
        readiness = Readiness(views, 10, 1.0, 0.0, 2, 2, ())
        rows: list[dict[str, Any]] = []
        for preset in presets:
            for pts in points:
                for mv in max_views:
                    params = load_params(PARAMS_FILE, {
                        "max_views": int(mv), "points": pts,
                        "output_file": str(out / f"{preset}_{pts}_{mv}.yaml")})
                    walls, cpus, rms, worst = [], [], [], []
                    error = ""
                    for s in seeds:
                        cam, dets = sets[(preset, s)]
                        c0, t0 = time.process_time(), time.perf_counter()
                        with SolveWorker() as worker:
                            outcome = run_solve(dets, BOARD, cam.size, params, readiness,
                                                worker=worker, stopping=threading.Event())
                        walls.append(time.perf_counter() - t0)
                        cpus.append(time.process_time() - c0)
                        if not outcome.success:
                            error = outcome.message
                            # NaN keeps the per-set lists aligned across max_views.
                            rms.append(math.nan)
                            worst.append(math.nan)
                            continue
                        r, m = _score(cam, outcome.result)
                        rms.append(r)
                        worst.append(m)
                    solved = [(r, m) for r, m in zip(rms, worst, strict=True)
                              if math.isfinite(r)]
                    row: dict[str, Any] = {
                        "preset": preset, "points": pts, "views": views, "max_views": mv,
                        "wall_s": statistics.median(walls), "cpu_s": statistics.median(cpus),
                        "walls_s": walls, "sets": len(solved), "rms_sets_px": rms,
                        "rms_px": statistics.median(r for r, _ in solved) if solved
                        else math.nan,
                        "max_px": statistics.median(m for _, m in solved) if solved
                        else math.nan}
                    if error:
                        row["error"] = error
                    rows.append(row)
                    log(f"session {preset:6s} {pts:7s} {views} views, max_views={mv:3d}: "
                        f"{row['wall_s']:6.2f} s wall ({row['cpu_s']:6.2f} s CPU), "
                        f"{row['rms_px']:.4f} px RMS from the truth" + (
                            f" [{error}]" if error else ""))
    return rows


# Stages of calibrate() and the functions whose cumulative time is theirs.
STAGES: tuple[tuple[str, tuple[tuple[str, str], ...]], ...] = (
    ("views: correspondences and checks", (("views.py", "view_points"),
                                           ("views.py", "view_problem"),
                                           ("views.py", "check_views"),
                                           ("pipeline.py", "_layout_check"))),
    ("selection (select_views)", (("views.py", "select_views"),)),
    ("the solve (2 OpenCV stages + weighted LM, centre passes, outlier rounds)",
     (("solve.py", "solve"), ("solve.py", "residuals"), ("pipeline.py", "_reject"),
      ("views.py", "lens_corrected_centers"))),
    ("cross-validation (5 folds)", (("quality.py", "cross_validate"),)),
    ("covariance (intrinsic_covariance, parameter_effect_px)",
     (("quality.py", "intrinsic_covariance"), ("quality.py", "parameter_effect_px"))),
)


def profile_case(preset: str, points: str, views: int, max_views: int, *,
                 seed: int = SEED, set_size: int | None = None,
                 top: int = 12) -> dict[str, Any]:
    """cProfile one :func:`calibrate` run and split its time into stages.

    Args:
        preset, points, views, max_views: the case (views from :func:`truth_views` with the
            seed :func:`solve_time_rows` gives the preset).
        seed: as in :func:`solve_time_rows`.
        set_size: the views are the first ``views`` of a set this large (as
            :func:`solve_time_rows` takes them from its largest N; default ``views``).
        top: entries of the own-time ranking to keep.

    Returns:
        ``total_s`` CPU seconds (profiled, so somewhat slower than unprofiled),
        ``wall_s`` its wall time, ``stages``: list of (stage, cumulative CPU seconds)
        with ``other`` the rest, ``cross_validation_parts``: (part, CPU seconds) within
        the cross-validation, ``top``: list of (function file:line, calls, own CPU
        seconds, cumulative CPU seconds).
    """
    cam, every = truth_views(preset, max(views, set_size or views), preset_seed(preset, seed))
    dets = every[:views]
    # Profiled in CPU seconds: on shared cores wall-clock shares would move with the
    # neighbours' load, not with where this process spends its work.
    prof = cProfile.Profile(time.process_time)
    t0, c0 = time.perf_counter(), time.process_time()
    prof.enable()
    calibrate(dets, BOARD, image_size=cam.size, points=points, max_views=max_views)
    prof.disable()
    total = time.process_time() - c0
    wall = time.perf_counter() - t0
    stats = pstats.Stats(prof)
    table: dict[tuple[str, int, str], tuple[Any, ...]] = stats.stats  # type: ignore[attr-defined]

    def cumulative(file: str, name: str) -> float:
        return sum(v[3] for k, v in table.items() if k[0].endswith(f"calibrate/{file}")
                   and k[2] == name)

    def called_from(file: str, name: str, caller: str) -> float:
        # Cumulative time of ``name`` in the calls made by ``caller`` only.
        return sum(t[3] for k, v in table.items()
                   if k[0].endswith(f"calibrate/{file}") and k[2] == name
                   for c, t in v[4].items() if c[2] == caller)

    stages = [(stage, sum(cumulative(f, n) for f, n in funcs)) for stage, funcs in STAGES]
    stages.append(("other (final geometry, sanity, warnings)",
                   max(total - sum(s for _, s in stages), 0.0)))
    # Within the cross-validation: the folds' solves and the held-out views' poses.
    parts = [("  of which the folds' LM solves (bundle_adjust)",
              called_from("lm.py", "bundle_adjust", "cross_validate")),
             ("  of which the held-out views' poses (refine_pose, estimate_pose)",
              called_from("model.py", "refine_pose", "cross_validate")
              + called_from("model.py", "estimate_pose", "cross_validate"))]
    own = sorted(table.items(), key=lambda kv: -kv[1][2])[:top]
    top_rows = [(f"{Path(k[0]).name}:{k[1]}({k[2]})" if k[1] else k[2], int(v[1]),
                 float(v[2]), float(v[3])) for k, v in own]
    return {"preset": preset, "points": points, "views": views, "max_views": max_views,
            "total_s": total, "wall_s": wall, "stages": stages,
            "cross_validation_parts": parts,
            "top": top_rows}


# --- plot -----------------------------------------------------------------------------------
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_BLACK = (0, 0, 0)
_RED = (30, 30, 220)
# BGR per (preset, points)
_COLOURS = {("webcam", "corners"): (180, 90, 20), ("webcam", "centers"): (230, 170, 90),
            ("hd", "corners"): (20, 110, 230), ("hd", "centers"): (60, 170, 60),
            ("wide", "corners"): (140, 40, 140), ("wide", "centers"): (200, 120, 200),
            ("fisheye", "corners"): (60, 60, 60), ("fisheye", "centers"): (150, 150, 150)}


def plot_solve_time(rows: Sequence[dict[str, Any]], default: int,
                    title: str = "") -> np.ndarray:
    """BGR plot of solve time (log scale) against the number of views.

    One curve per (preset, points, setting): solid for max_views = N (every view), dashed
    for the default max_views; a red line at the 5 s budget.

    Args:
        rows: :func:`solve_time_rows` rows (failed ones are skipped).
        default: the default max_views, for the legend.
        title: the first line of the title (default: what the figure shows).
    """
    good = [r for r in rows if "wall_s" in r and r["wall_s"] > 0]
    width, height, left, right, top, bottom = 1100, 660, 80, 300, 70, 60
    canvas = np.full((height, width, 3), 255, np.uint8)
    x_max = max([r["views"] for r in good] + [10])
    times = [r["wall_s"] for r in good] + [BUDGET_S]
    lo = 10.0 ** math.floor(math.log10(min(times)))
    # Top of the axis: the first 1, 2 or 5 x 10^k above the slowest time.
    hi = min(m * 10.0 ** math.ceil(math.log10(max(times)) - 1) for m in (1, 2, 5, 10)
             if m * 10.0 ** math.ceil(math.log10(max(times)) - 1) >= max(times))
    plot_w, plot_h = width - left - right, height - top - bottom

    def xy(views: float, seconds: float) -> tuple[int, int]:
        fx = views / x_max
        fy = (math.log10(seconds) - math.log10(lo)) / (math.log10(hi) - math.log10(lo))
        return round(left + fx * plot_w), round(top + (1.0 - fy) * plot_h)

    decade = lo
    while decade <= hi * 1.0001:  # y grid at 1, 2, 5 per decade
        for m in (1, 2, 5):
            v = decade * m
            if v > hi * 1.0001:
                break
            _, y = xy(0, v)
            cv2.line(canvas, (left, y), (left + plot_w, y),
                     (215, 215, 215) if m == 1 else (238, 238, 238), 1)
            cv2.putText(canvas, f"{v:g}", (left - 45, y + 5), _FONT, 0.45, _BLACK, 1,
                        cv2.LINE_AA)
        decade *= 10
    for n in sorted({r["views"] for r in good} | {0}):
        x, y0 = xy(n, lo)
        cv2.line(canvas, (x, top), (x, y0), (238, 238, 238), 1)
        cv2.putText(canvas, str(n), (x - 10, y0 + 20), _FONT, 0.45, _BLACK, 1, cv2.LINE_AA)
    cv2.rectangle(canvas, (left, top), (left + plot_w, top + plot_h), _BLACK, 1)
    _, yb = xy(0, BUDGET_S)
    cv2.line(canvas, (left, yb), (left + plot_w, yb), _RED, 1, cv2.LINE_AA)
    cv2.putText(canvas, f"{BUDGET_S:g} s", (left + plot_w - 40, yb - 6), _FONT, 0.5, _RED, 1,
                cv2.LINE_AA)
    legend_y = top + 10
    keys = sorted({(r["preset"], r["points"], r["setting"]) for r in good},
                  key=lambda k: (PRESETS.index(k[0]) if k[0] in PRESETS else 9,
                                 POINTS.index(k[1]), k[2] != "all"))
    for preset, points, setting in keys:
        colour = _COLOURS.get((preset, points), _BLACK)
        curve = sorted((r["views"], r["wall_s"]) for r in good
                       if (r["preset"], r["points"], r["setting"]) == (preset, points,
                                                                       setting))
        pts = [xy(n, s) for n, s in curve]
        for a, b in itertools.pairwise(pts):
            if setting == "all":
                cv2.line(canvas, a, b, colour, 2, cv2.LINE_AA)
            else:
                dashed_line(canvas, a, b, colour)
        for q in pts:
            if setting == "all":
                cv2.circle(canvas, q, 4, colour, -1, cv2.LINE_AA)
            else:
                cv2.rectangle(canvas, (q[0] - 4, q[1] - 4), (q[0] + 4, q[1] + 4), colour, 2)
        lx = left + plot_w + 20
        if setting == "all":
            cv2.line(canvas, (lx, legend_y), (lx + 40, legend_y), colour, 2, cv2.LINE_AA)
            cv2.circle(canvas, (lx + 20, legend_y), 4, colour, -1, cv2.LINE_AA)
        else:
            dashed_line(canvas, (lx, legend_y), (lx + 40, legend_y), colour)
            cv2.rectangle(canvas, (lx + 16, legend_y - 4), (lx + 24, legend_y + 4), colour, 2)
        label = f"{preset} {points}, " + ("all views" if setting == "all"
                                           else f"max_views {default}")
        cv2.putText(canvas, label, (lx + 50, legend_y + 5), _FONT, 0.45, _BLACK, 1,
                    cv2.LINE_AA)
        legend_y += 26
    head = title or "calibrate() solve time, wall seconds (median), log scale; 2 shared cores"
    cv2.putText(canvas, head, (left, 28), _FONT, 0.6, _BLACK, 1, cv2.LINE_AA)
    cv2.putText(canvas, f"solid: max_views = N (every view solved); dashed: max_views = "
                f"{default} (default); red: {BUDGET_S:g} s", (left, 52), _FONT, 0.45, _BLACK,
                1, cv2.LINE_AA)
    cv2.putText(canvas, "views N", (left + plot_w // 2 - 30, height - 15), _FONT, 0.5,
                _BLACK, 1, cv2.LINE_AA)
    cv2.putText(canvas, "s", (left - 45, top - 10), _FONT, 0.5, _BLACK, 1, cv2.LINE_AA)
    return canvas


# --- tables ---------------------------------------------------------------------------------
def _fmt(row: dict[str, Any] | None) -> tuple[str, str, str]:
    """(wall, CPU, RMS) cells of a row."""
    if row is None:
        return "", "", ""
    if "error" in row and "wall_s" not in row:
        return "failed", "", ""
    runs = len(row.get("walls_s", ()))
    mark = "" if runs != 1 else " (1 run)"
    return f"{row['wall_s']:.2f}{mark}", f"{row['cpu_s']:.2f}", f"{row['rms_px']:.4f}"


def markdown_grid(rows: Sequence[dict[str, Any]], default: int) -> str:
    """The solve-time table: one line per (preset, points, N), both settings side by side."""
    lines = [f"| camera | points | views N | max_views = N: wall s | CPU s | RMS px | "
             f"max_views = {default}: wall s | CPU s | RMS px |",
             "|---|---|---|---|---|---|---|---|---|"]
    keyed = {(r["preset"], r["points"], r["views"], r["setting"]): r for r in rows}
    for preset, points, n in sorted({(r["preset"], r["points"], r["views"]) for r in rows},
                                    key=lambda k: (PRESETS.index(k[0]) if k[0] in PRESETS
                                                   else 9, POINTS.index(k[1]), k[2])):
        a = keyed.get((preset, points, n, "all"))
        d = keyed.get((preset, points, n, "default"))
        d_cells = ("(same)", "", "") if d is not None and d.get("same_as_all") else _fmt(d)
        lines.append(f"| {preset} | {points} | {n} | " + " | ".join(_fmt(a)) + " | "
                     + " | ".join(d_cells) + " |")
    return "\n".join(lines)


def paired_ratio(row: dict[str, Any], reference: dict[str, Any] | None) -> float:
    """Median over the view sets of row's RMS / reference's RMS on the same set (NaN if
    there is no reference or no set both solved)."""
    if reference is None:
        return math.nan
    ratios = [a / b for a, b in zip(row.get("rms_sets_px", ()),
                                    reference.get("rms_sets_px", ()), strict=False)
              if math.isfinite(a) and math.isfinite(b) and b > 0]
    return statistics.median(ratios) if ratios else math.nan


def markdown_session(rows: Sequence[dict[str, Any]], default: int | None = None) -> str:
    """The session-path table: time and accuracy per max_views; with ``default``, each
    row's RMS against the default max_views' on the same view sets (paired)."""
    lines = ["| camera | points | max_views | wall s (median) | CPU s | runs: wall s | "
             "RMS px from the truth: median / mean | max px | RMS / default's, paired |",
             "|---|---|---|---|---|---|---|---|---|"]
    refs = {(r["preset"], r["points"]): r for r in rows if r["max_views"] == default}
    for r in rows:
        runs = ", ".join(f"{w:.1f}" for w in r["walls_s"])
        err = " (failed: " + r["error"][:40] + ")" if "error" in r else ""
        ratio = paired_ratio(r, refs.get((r["preset"], r["points"])))
        solved = [x for x in r.get("rms_sets_px", ()) if math.isfinite(x)]
        mean = statistics.mean(solved) if solved else math.nan
        lines.append(f"| {r['preset']} | {r['points']} | {r['max_views']} | "
                     f"{r['wall_s']:.2f} | {r['cpu_s']:.2f} | {runs} | "
                     f"{r['rms_px']:.4f} / {mean:.4f} | {r['max_px']:.4f}{err} | "
                     + (f"{ratio:.2f} |" if math.isfinite(ratio) else " |"))
    return "\n".join(lines)


def markdown_profile(prof: dict[str, Any]) -> str:
    """The profile breakdown: stages, then the functions with the most own time."""
    total = prof["total_s"]
    lines = [f"Profile of `calibrate` ({prof['preset']}, {prof['points']}, {prof['views']} "
             f"views, max_views = {prof['max_views']}; {total:.2f} s CPU under cProfile, "
             f"{prof.get('wall_s', math.nan):.2f} s wall):", "",
             "| stage | CPU s | share |", "|---|---|---|"]
    for s, t in prof["stages"]:
        lines.append(f"| {s} | {t:.2f} | {100 * t / total:.0f} % |")
        if s.startswith("cross-validation"):
            lines += [f"| {p} | {u:.2f} | {100 * u / total:.0f} % |"
                      for p, u in prof.get("cross_validation_parts", ())]
    lines += ["", "| function (own time) | calls | own CPU s | cumulative CPU s |",
              "|---|---|---|---|"]
    lines += [f"| `{f}` | {c} | {o:.2f} | {cu:.2f} |" for f, c, o, cu in prof["top"]]
    return "\n".join(lines)


def _load_average() -> str:
    try:
        return Path("/proc/loadavg").read_text().split()[0]
    except OSError:
        return "?"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true",
                        help="webcam only, 10/40/80 views, one run each, a short sweep")
    parser.add_argument("--sections", default="grid,session,profile",
                        help="comma-separated: grid (calibrate per N), session (run_solve per "
                             "max_views), profile (of the slowest default grid case by CPU "
                             "time; without grid: 200 webcam views, corners)")
    parser.add_argument("--presets", default=",".join(PRESETS), help="camera presets")
    parser.add_argument("--repeats", type=int, default=3, help="runs per grid case (median)")
    parser.add_argument("--repeat-cap", type=float, default=30.0,
                        help="a grid case whose first run takes longer (s) runs once")
    parser.add_argument("--sets", type=int, default=SESSION_SETS,
                        help="view sets of the session rows (one run each; medians)")
    parser.add_argument("--sweep", default=",".join(map(str, SWEEP_MAX_VIEWS)),
                        help="max_views values of the session rows (the default is added)")
    parser.add_argument("--plot", default=None,
                        help="where to write the PNG (default docs/solve_time.png; with "
                             "--quick /tmp/artcal_bench/solve_time_quick.png)")
    parser.add_argument("--out", default="/tmp/artcal_bench/solve_time.json",
                        help="where to write the figures as JSON")
    args = parser.parse_args(argv)
    warnings.simplefilter("ignore", RuntimeWarning)
    default = default_max_views()
    sections = set(args.sections.split(","))
    presets = ("webcam",) if args.quick else tuple(args.presets.split(","))
    counts = QUICK_VIEW_COUNTS if args.quick else VIEW_COUNTS
    repeats = 1 if args.quick else args.repeats
    sweep = (20, default) if args.quick else tuple(sorted(
        {*(int(m) for m in args.sweep.split(",")), default}))
    seeds = tuple(SEED + k for k in range(1 if args.quick else max(1, args.sets)))
    print(f"load average at start {_load_average()}; cv2 threads {cv2.getNumThreads()}; "
          f"default max_views {default} ({PARAMS_FILE.name})", flush=True)
    start = time.monotonic()
    log = functools.partial(print, flush=True)
    figures: dict[str, Any] = {}
    grid: list[dict[str, Any]] = []
    if "grid" in sections:
        grid = solve_time_rows(presets, counts, repeats=repeats, repeat_cap_s=args.repeat_cap,
                               log=log)
        figures["grid"] = grid
    if "session" in sections:
        figures["session"] = session_rows(presets, sweep, seeds=seeds, log=log)
    if "profile" in sections:
        # By CPU time: on shared cores the slowest wall time is whichever case the
        # neighbours' load hit hardest.
        timed = [r for r in grid if r["setting"] == "default" and "cpu_s" in r]
        case = (max(timed, key=lambda r: r["cpu_s"]) if timed
                else {"preset": presets[0], "points": "corners", "views": SESSION_VIEWS})
        figures["profile"] = profile_case(case["preset"], case["points"], case["views"],
                                          default, set_size=max(counts) if timed else None)
    print(f"\nload average at the end {_load_average()}; {time.monotonic() - start:.0f} s\n")
    if grid:
        print(markdown_grid(grid, default), "\n")
    if "session" in figures:
        print(f"Session path (run_solve), {SESSION_VIEWS} collected views, {len(seeds)} view "
              "set(s):\n")
        print(markdown_session(figures["session"], default), "\n")
    if "profile" in figures:
        print(markdown_profile(figures["profile"]))
    if grid:
        plot_path = Path(args.plot) if args.plot else (
            Path("/tmp/artcal_bench/solve_time_quick.png") if args.quick
            else ROOT / "docs" / "solve_time.png")
        plot_path.parent.mkdir(parents=True, exist_ok=True)
        if not cv2.imwrite(str(plot_path), plot_solve_time(grid, default)):
            print(f"cannot write {plot_path}", file=sys.stderr)
            return 1
        print(f"\nplot in {plot_path}")
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(figures, indent=2))
    print(f"figures in {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
