"""Does next-pose guidance need fewer views? Simulated sessions against a known camera.

    python -m bench.guidance              # webcam, hd, wide, each with the default and an A4
                                          # board: 20 sessions each (hours on 2 busy cores)
    python -m bench.guidance --cases hd:a4 --json hd_a4.json   # one case (run several at once)
    python -m bench.guidance --merge *.json                    # their tables together
    python -m bench.guidance --quick      # webcam, 2 sessions of 8 views (~30 s)

Each session starts from the same random view (``--start-views``: 1, or 3 as earlier runs
did; poses and noise) for every strategy, then adds one view at a time up to
``--max-views``, re-solving after each from the second view on, as the node's live solve
does (the bundle adjustment warm-started from the last solve, a new view's pose from the
current camera) and measuring
the true projection difference (:func:`projection_difference` against the preset's camera)
and the solve's own projection uncertainty RMS. The board is the default one (19 x 9
markers, 1.5 x 0.7 m) or one printed on A4 paper (7 x 5 markers of 30 mm). Three ways to
choose the next view:

- ``guided``: :func:`next_pose` from the current solve (:func:`first_pose`, from a
  provisional camera and the intrinsics' prior, before the first solve at 2 views); a
  virtual user shows that pose with human-sized errors: the board's centre off by a
  Gaussian 10 % of its distance along each camera axis, the board turned by a Gaussian
  10 degrees about a random axis.
- ``random``: random holdable poses (:func:`holdable_pose`: anywhere over the image, board
  filling 20-80 % of it, tilted 0-50 degrees in any direction, rolled up to 15 degrees).
- ``bars``: the board waved smoothly from one random holdable pose to the next (10 frames
  apart, a camera stream); a frame is kept as a view only when camera_calibration's
  X / Y / size / skew test calls it new (the Manhattan distance of its four parameters to
  every kept view's exceeds 0.2; the parameters from the outer corners of the part of the
  grid in view); frames it refuses cost no view.

Detections are the true camera's projection of the marker corners (points = corners, the
default) inside the image plus Gaussian noise of 0.04 px per axis (the detector's corner
error on clean frames is 0.03-0.05 px), not rendered images: the strategies differ only in
where the board goes, and rendering 3 x 20 sessions of up to 40 frames would take hours.
A view needs at least 6 markers' corners in the image (else the user shows the board again).

Reported, median over the sessions (a session that never gets there counts as more than
``--max-views``): views until the true difference first reaches 0.1 px and 0.05 px, views
from which on it stays at or below them to the session's end, and views until the solve's
uncertainty reaches 0.05 px; in brackets the guided median over this strategy's. Also the
time of one :func:`next_pose` call at 40 views.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.model import SolveOptions, free_parameters
from artcal_ros.core.calibrate.quality import (
    intrinsic_covariance,
    parameter_effect_px,
    projection_difference,
    solution_camera,
)
from artcal_ros.core.calibrate.solve import (
    Solution,
    ViewPoints,
    bundle_adjust,
    estimate_pose,
    residuals,
    solve,
)
from artcal_ros.core.errors import CalibrationError
from artcal_ros.core.live.guidance import holdable_pose, next_pose
from artcal_ros.core.live.guidance_start import first_pose
from artcal_ros.core.live.live_solve import MIN_VIEWS as SOLVE_VIEWS  # as the node solves
from artcal_ros.synth import Camera
from artcal_ros.synth.poses import ease_between

BOARD = Board()
# A board printed on A4 paper: 7 x 5 markers of 30 mm, 10 mm apart (270 x 190 mm)
A4_BOARD = Board(cols=7, rows=5, marker_length=0.03, marker_separation=0.01)
BOARDS = {"default": BOARD, "a4": A4_BOARD}
CASES = ("webcam", "hd", "wide", "webcam:a4", "hd:a4", "wide:a4")
STRATEGIES = ("guided", "random", "bars")
THRESHOLDS_PX = (0.1, 0.05)
NOISE_PX = 0.04
START_VIEWS = 1  # shared random views a session starts from (--start-views)
MIN_POINTS = 24  # 6 markers' corners
POSITION_ERROR = 0.10  # of the board's distance, per camera axis (1 sigma)
TILT_ERROR_DEG = 10.0  # 1 sigma, about a random axis
BARS_THRESHOLD = 0.2  # camera_calibration's is_good_sample distance
MAX_FRAMES = 5000  # frames the bars strategy may look at for one view
WAVE_FRAMES = 10  # frames from one random pose to the next in the bars strategy's stream
SEED = 2300
# radial terms solved per preset: the wide lens's k3 is part of its true distortion
K_COEFFICIENTS = {"webcam": 2, "hd": 2, "wide": 3}


@dataclass
class Session:
    """One simulated session of one strategy: the true projection difference after each
    view (index = views used - 1; NaN before the first solve)."""

    preset: str
    strategy: str
    seed: int
    difference_px: list[float] = field(default_factory=list)
    uncertainty_px: list[float] = field(default_factory=list)
    frames_seen: int = 0

    def views_to(self, threshold_px: float) -> int | None:
        """Views used when the difference first reached ``threshold_px`` (None: never)."""
        return _first_at_or_below(self.difference_px, threshold_px)

    def views_staying(self, threshold_px: float) -> int | None:
        """Views from which on the difference stayed at or below ``threshold_px`` to the
        session's end (None: it was above at the end)."""
        d = self.difference_px
        if not d or not d[-1] <= threshold_px:
            return None
        k = len(d)
        while k > 0 and d[k - 1] <= threshold_px:
            k -= 1
        return k + 1

    def views_to_uncertainty(self, threshold_px: float) -> int | None:
        """Views used when the solve's own projection uncertainty RMS first reached
        ``threshold_px`` (what the node's readiness waits for)."""
        return _first_at_or_below(self.uncertainty_px, threshold_px)


def _first_at_or_below(values: list[float], threshold: float) -> int | None:
    for k, v in enumerate(values):
        if math.isfinite(v) and v <= threshold:
            return k + 1
    return None


class World:
    """The true camera, the board and a detector of given noise."""

    def __init__(self, preset: str, rng: np.random.Generator, board: Board = BOARD) -> None:
        self.cam = Camera.preset(preset)
        self.size = self.cam.size
        self.board = board
        self.obj = board.object_corners().reshape(-1, 3)
        self.ids = np.repeat(board.ids, 4)
        self.rng = rng
        self._wave: list[tuple[np.ndarray, np.ndarray]] = []
        self._key: tuple[np.ndarray, np.ndarray] | None = None

    def inside(self, rvec: np.ndarray, tvec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(true image points (M, 2), which are in view (M,) bool) for T_cam_board."""
        R = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
        cam_pts = self.obj @ R.T + np.asarray(tvec, np.float64)
        px = self.cam.project(self.obj, rvec, tvec)
        w, h = self.size
        with np.errstate(invalid="ignore"):
            ok = ((cam_pts[:, 2] > 0.05) & np.all(np.isfinite(px), axis=1) & (px[:, 0] >= 0)
                  & (px[:, 0] <= w - 1) & (px[:, 1] >= 0) & (px[:, 1] <= h - 1))
            # no fold of the distortion model: the field the lens maps onto the image
            tan = np.hypot(cam_pts[:, 0], cam_pts[:, 1]) / np.maximum(cam_pts[:, 2], 1e-9)
            ok &= tan <= self.max_tan()
        return px, ok

    def max_tan(self) -> float:
        if not hasattr(self, "_max_tan"):
            w, h = self.size
            border = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1],
                               [(w - 1) / 2, 0], [0, (h - 1) / 2]], np.float64)
            rays, ok = self.cam.unproject(border)
            self._max_tan = float(np.max(np.hypot(rays[ok, 0], rays[ok, 1]) / rays[ok, 2]))
        return self._max_tan

    def view(self, rvec: np.ndarray, tvec: np.ndarray, index: int) -> ViewPoints | None:
        """The noisy detection of T_cam_board, None with too few points in view."""
        px, ok = self.inside(rvec, tvec)
        if ok.sum() < MIN_POINTS:
            return None
        noisy = px[ok] + self.rng.normal(0.0, NOISE_PX, (int(ok.sum()), 2))
        return ViewPoints(index, f"view{index}", self.obj[ok], noisy, self.ids[ok],
                          sigma_px=np.full(int(ok.sum()), NOISE_PX))

    def waving_frame(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """The next frame of a board waved smoothly from one random holdable pose to the
        next, WAVE_FRAMES frames apart (a camera stream at about 10 frames a pose)."""
        if not self._wave:
            last = self._key if self._key is not None else self.random_pose(rng)
            self._key = self.random_pose(rng)
            self._wave = ease_between([last, self._key], WAVE_FRAMES + 1,
                                      frames_per_key=WAVE_FRAMES)[1:]
        return self._wave.pop(0)

    def random_pose(self, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """A random holdable pose of the board (see the module docstring)."""
        return holdable_pose(self.cam.K, self.board, self.size,
                             anchor=(float(rng.uniform()), float(rng.uniform())),
                             fill=float(rng.uniform(0.2, 0.8)),
                             tilt_direction_deg=float(rng.uniform(0.0, 360.0)),
                             tilt_deg=float(rng.uniform(0.0, 50.0)),
                             roll_deg=float(rng.uniform(-15.0, 15.0)))


def human_error(board: Board, rvec: np.ndarray, tvec: np.ndarray,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """T_cam_board as a person holds it when asked for (rvec, tvec): the board's centre off
    by POSITION_ERROR of its distance per axis, turned TILT_ERROR_DEG about a random axis."""
    x0, y0, x1, y1 = board.extent_m
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    R = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
    c = R @ centre + tvec
    c_new = c + rng.normal(0.0, POSITION_ERROR * float(np.linalg.norm(c)), 3)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    turn = cv2.Rodrigues((axis * math.radians(rng.normal(0.0, TILT_ERROR_DEG))).reshape(3, 1))[0]
    R_new = turn @ R
    return cv2.Rodrigues(R_new)[0].ravel(), c_new - R_new @ centre


def bars_parameters(board: Board, px: np.ndarray, ok: np.ndarray,
                    size: tuple[int, int]) -> np.ndarray:
    """camera_calibration's (X, Y, size, skew) of a view, from the outer corners of the part
    of the grid in view (the board-frame rectangle spanning its visible points).

    Args:
        px: (M, 2) the image of every marker corner of ``board``; ok: (M,) which are in view.
    """
    w, h = size
    obj = board.object_corners().reshape(-1, 3)[ok]
    img = px[ok]
    # the visible point nearest each corner of the visible part's board-frame rectangle
    lo, hi = obj[:, :2].min(axis=0), obj[:, :2].max(axis=0)
    targets = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    quad = np.array([img[np.argmin(np.linalg.norm(obj[:, :2] - t, axis=1))] for t in targets])
    up_left, up_right, down_right, down_left = quad
    a = up_right - up_left
    b = down_right - up_right
    c = down_left - down_right
    p, q = b + c, a + b
    area = abs(p[0] * q[1] - p[1] * q[0]) / 2.0
    border = math.sqrt(area)
    x = min(1.0, max(0.0, (float(img[:, 0].mean()) - border / 2) / (w - border)))
    y = min(1.0, max(0.0, (float(img[:, 1].mean()) - border / 2) / (h - border)))
    side_a, side_b = up_left - up_right, down_right - up_right
    cos = float(np.dot(side_a, side_b) / (np.linalg.norm(side_a) * np.linalg.norm(side_b)))
    skew = min(1.0, 2.0 * abs(math.pi / 2 - math.acos(max(-1.0, min(1.0, cos)))))
    return np.array([x, y, math.sqrt(area / (w * h)), skew])


def run_session(preset: str, strategy: str, seed: int, max_views: int, *,
                board: Board = BOARD, start_views: int = START_VIEWS,
                timings: list[tuple[int, float]] | None = None) -> Session:
    """One session of ``strategy``; the first ``start_views`` views are the same random
    views for every strategy of the same seed."""
    # The start views (poses and noise) come from the seed alone, the rest from the strategy.
    start_rng = np.random.default_rng(seed)
    rng = np.random.default_rng([seed, STRATEGIES.index(strategy)])
    world = World(preset, start_rng, board)
    model = "plumb_bob"
    options = SolveOptions(k_coefficients=K_COEFFICIENTS.get(preset, 2))
    free = free_parameters(model, options=options)
    session = Session(preset, strategy, seed)
    views: list[ViewPoints] = []
    bars_db: list[np.ndarray] = []
    while len(views) < start_views:
        r, t = world.random_pose(start_rng)
        v = world.view(r, t, len(views))
        if v is not None:
            views.append(v)
            if strategy == "bars":
                bars_db.append(bars_parameters(board, *world.inside(r, t), world.size))
    session.frames_seen = start_views
    world.rng = rng
    sol: Solution | None = None
    if len(views) >= SOLVE_VIEWS:
        try:
            sol, _ = solve(views, world.size, model, options=options)
        except CalibrationError:
            sol = None
    session.difference_px = [math.nan] * (len(views) - 1)
    session.uncertainty_px = [math.nan] * (len(views) - 1)
    solved = len(views) >= SOLVE_VIEWS
    session.difference_px.append(_difference(world, sol) if solved else math.nan)
    session.uncertainty_px.append(_uncertainty(views, sol, world.size) if solved else math.nan)
    while len(views) < max_views:
        new = _next_view(world, strategy, views, sol, rng, bars_db, session, timings,
                         options)
        if new is None:
            break
        views.append(new)
        if len(views) < SOLVE_VIEWS:
            session.difference_px.append(math.nan)
            session.uncertainty_px.append(math.nan)
            continue
        sol = _resolve(views, sol, world.size, model, options, free)
        session.difference_px.append(_difference(world, sol))
        session.uncertainty_px.append(_uncertainty(views, sol, world.size))
    return session


def _next_view(world: World, strategy: str, views: list[ViewPoints], sol: Solution | None,
               rng: np.random.Generator, bars_db: list[np.ndarray], session: Session,
               timings: list[tuple[int, float]] | None,
               options: SolveOptions) -> ViewPoints | None:
    index = len(views)
    if strategy == "guided" and (sol is not None or len(views) < SOLVE_VIEWS):
        t0 = time.perf_counter()
        suggestion = (next_pose(views, sol, world.board, world.size) if sol is not None
                      else first_pose(views, world.board, world.size, options=options))
        if timings is not None:
            timings.append((len(views), time.perf_counter() - t0))
        if suggestion is not None:
            for _attempt in range(10):
                session.frames_seen += 1
                v = world.view(*human_error(world.board, suggestion.rvec, suggestion.tvec,
                                            rng), index)
                if v is not None:
                    return v
    if strategy == "bars":
        for _frame in range(MAX_FRAMES):
            session.frames_seen += 1
            r, t = world.waving_frame(rng)
            px, ok = world.inside(r, t)
            if ok.sum() < MIN_POINTS:
                continue
            params = bars_parameters(world.board, px, ok, world.size)
            if min(float(np.abs(params - p).sum()) for p in bars_db) > BARS_THRESHOLD:
                bars_db.append(params)
                return world.view(r, t, index)
        return None
    for _frame in range(100):  # random (and guided without a solve yet)
        session.frames_seen += 1
        v = world.view(*world.random_pose(rng), index)
        if v is not None:
            return v
    return None


def _resolve(views: list[ViewPoints], sol: Solution | None, size: tuple[int, int],
             model: str, options: SolveOptions, free: tuple[str, ...]) -> Solution | None:
    """The solve of ``views``: warm-started from ``sol`` (the last view's pose from its
    intrinsics), from scratch when there is none or the warm start fails."""
    if sol is not None:
        try:
            r, t = estimate_pose(views[-1], sol.camera_matrix, sol.dist_coeffs, model)
            K, D, rv, tv = bundle_adjust(views, sol.camera_matrix, sol.dist_coeffs, model,
                                         free=free, poses=(np.vstack([sol.rvecs, r]),
                                                           np.vstack([sol.tvecs, t])),
                                         tolerance=1e-10)
            if np.all(np.isfinite(K)) and np.all(np.isfinite(D)):
                return Solution(K, D, model, rv, tv, free)
        except (CalibrationError, np.linalg.LinAlgError, cv2.error):
            pass
    try:
        return solve(views, size, model, options=options)[0]
    except CalibrationError:
        return None


def _difference(world: World, sol: Solution | None) -> float:
    if sol is None:
        return math.inf
    d = projection_difference(world.cam, solution_camera(sol, world.size))[0]
    return d if math.isfinite(d) else math.inf


def _uncertainty(views: list[ViewPoints], sol: Solution | None,
                 size: tuple[int, int]) -> float:
    """The solve's projection uncertainty RMS over the image, pixels (inf without a solve)."""
    if sol is None:
        return math.inf
    cov, _ = intrinsic_covariance(views, sol, residuals(views, sol))
    u = parameter_effect_px(sol, size, cov)[1]
    return u if math.isfinite(u) else math.inf


def time_next_pose(preset: str, n_views: int = 40, repeats: int = 5, *,
                   board: Board = BOARD) -> float:
    """Median seconds of one :func:`next_pose` call at ``n_views`` random views."""
    rng = np.random.default_rng(SEED - 1)
    world = World(preset, rng, board)
    views: list[ViewPoints] = []
    while len(views) < n_views:
        v = world.view(*world.random_pose(rng), len(views))
        if v is not None:
            views.append(v)
    options = SolveOptions(k_coefficients=K_COEFFICIENTS.get(preset, 2))
    sol, _ = solve(views, world.size, "plumb_bob", options=options)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        next_pose(views, sol, board, world.size)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


# Measures of a session: (column name, views the session needed by that measure)
MEASURES: tuple[tuple[str, Callable[[Session], int | None]], ...] = (
    ("first <= 0.1 px", lambda s: s.views_to(0.1)),
    ("first <= 0.05 px", lambda s: s.views_to(0.05)),
    ("stays <= 0.1 px", lambda s: s.views_staying(0.1)),
    ("stays <= 0.05 px", lambda s: s.views_staying(0.05)),
    ("uncertainty <= 0.05 px", lambda s: s.views_to_uncertainty(0.05)),
)


def run(cases: tuple[str, ...], sessions: int, max_views: int, *,
        log: Callable[[str], None] = print,
        progress: Callable[[dict[str, Any]], None] | None = None,
        first: int = 0, start_views: int = START_VIEWS) -> dict[str, Any]:
    """Every session of every case and strategy; the rows of the tables.

    Args:
        cases: "preset" or "preset:board" (a name of BOARDS; default: the default board).
        progress: called with the result so far after every session's three strategies.
        first: the first session's number (its seed SEED + first).
        start_views: the shared random views every session starts from.
    """
    out: dict[str, Any] = {"cases": {}, "max_views": max_views, "sessions": sessions,
                           "start_views": start_views}
    for case in cases:
        preset, _, board_name = case.partition(":")
        board = BOARDS[board_name or "default"]
        label = f"{preset}, {board_name or 'default'} board"
        per: dict[str, list[Session]] = {s: [] for s in STRATEGIES}
        timings: list[tuple[int, float]] = []
        for k in range(first, first + sessions):
            for strategy in STRATEGIES:
                t0 = time.perf_counter()
                s = run_session(preset, strategy, SEED + k, max_views, board=board,
                                start_views=start_views, timings=timings)
                per[strategy].append(s)
                log(f"{label} session {k} {strategy}: views "
                    + ", ".join(f"{name} {fn(s)}" for name, fn in MEASURES)
                    + f"; frames {s.frames_seen}, {time.perf_counter() - t0:.1f} s")
            out["cases"][label] = _case_result(per, timings, math.nan)
            if progress is not None:
                progress(out)
        out["cases"][label] = _case_result(per, timings, time_next_pose(preset, board=board))
    return out


def _case_result(per: dict[str, list[Session]], timings: list[tuple[int, float]],
                 next_pose_s_at_40: float) -> dict[str, Any]:
    return {
        "sessions": {st: [{"seed": s.seed, "difference_px": s.difference_px,
                           "uncertainty_px": s.uncertainty_px,
                           "frames_seen": s.frames_seen} for s in ss]
                     for st, ss in per.items()},
        "views": {st: {name: [fn(s) for s in ss] for name, fn in MEASURES}
                  for st, ss in per.items()},
        "next_pose_s_at_40": next_pose_s_at_40,
        "next_pose_s_in_sessions": statistics.median([t for _, t in timings])
        if timings else math.nan,
    }


def _median(counts: list[int | None], max_views: int) -> float:
    """The median of views needed, sessions that never got there counted above the cap."""
    return float(statistics.median(c if c is not None else max_views + 1 for c in counts))


def markdown(result: dict[str, Any]) -> str:
    """The table docs/benchmarks.md shows: median views per strategy and measure, and the
    guided sessions' median against this strategy's (guided / this)."""
    cap = result["max_views"]
    names = [name for name, _ in MEASURES]
    lines = ["| camera, board | strategy | " + " | ".join(names) + " |",
             "|---|---|" + "---|" * len(names)]
    for label, r in result["cases"].items():
        for st in STRATEGIES:
            cells = []
            for name in names:
                m = _median(r["views"][st][name], cap)
                text = f"> {cap}" if m > cap else f"{m:g}"
                if st != "guided":
                    g = _median(r["views"]["guided"][name], cap)
                    text += f" ({g / m:.2f})"
                cells.append(text)
            lines.append(f"| {label} | {st} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def markdown_differences(result: dict[str, Any], at: tuple[int, ...] = (10, 20, 40)) -> str:
    """Median true projection difference (px) per strategy after ``at`` views, and the
    median of difference over the solve's uncertainty (at the same views)."""
    at = tuple(n for n in at if n <= result["max_views"])
    head = " | ".join(f"{n} views" for n in at)
    lines = [f"| camera, board | strategy | {head} | difference / uncertainty |",
             "|---|---|" + "---|" * (len(at) + 1)]
    for label, r in result["cases"].items():
        for st in STRATEGIES:
            sessions = r["sessions"][st]
            cells = []
            ratios = []
            for n in at:
                d = [s["difference_px"][n - 1] for s in sessions if len(s["difference_px"]) >= n]
                u = [s["uncertainty_px"][n - 1] for s in sessions
                     if len(s["uncertainty_px"]) >= n]
                cells.append(f"{statistics.median(d):.4f}" if d else "-")
                ratios.append(f"{statistics.median(x / y for x, y in zip(d, u, strict=True)):.2f}"
                              if d else "-")
            lines.append(f"| {label} | {st} | " + " | ".join(cells) + " | "
                         + " / ".join(ratios) + " |")
    return "\n".join(lines)


def merged(paths: list[Path]) -> dict[str, Any]:
    """The cases of several runs written by ``--json`` as one result (same sessions and
    views each)."""
    runs = [json.loads(p.read_text()) for p in paths]
    if len({r["max_views"] for r in runs}) != 1:
        raise SystemExit("--merge: the runs differ in --max-views")
    starts = {r.get("start_views", 3) for r in runs}  # runs before --start-views started at 3
    if len(starts) != 1:
        raise SystemExit("--merge: the runs differ in --start-views")
    out: dict[str, Any] = {"cases": {}, "max_views": runs[0]["max_views"],
                           "start_views": starts.pop()}
    for r in runs:
        for label, case in r["cases"].items():
            if label not in out["cases"]:
                out["cases"][label] = case
                continue
            have = out["cases"][label]  # the same case run in parts (--first): sessions joined
            for st in STRATEGIES:
                seen = {x["seed"] for x in have["sessions"][st]}
                new = [k for k, x in enumerate(case["sessions"][st]) if x["seed"] not in seen]
                have["sessions"][st] += [case["sessions"][st][k] for k in new]
                for name, _ in MEASURES:
                    have["views"][st][name] += [case["views"][st][name][k] for k in new]
            if not math.isfinite(have["next_pose_s_at_40"]):
                have["next_pose_s_at_40"] = case["next_pose_s_at_40"]
    # a run stopped early holds fewer sessions than asked for: say the fewest
    out["sessions"] = min(len(c["sessions"]["guided"]) for c in out["cases"].values())
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.guidance", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="webcam, 2 sessions, 8 views")
    parser.add_argument("--cases", default=",".join(CASES),
                        help="preset[:board] list, boards: " + ", ".join(BOARDS))
    parser.add_argument("--sessions", type=int, default=20)
    parser.add_argument("--max-views", type=int, default=40)
    parser.add_argument("--first", type=int, default=0,
                        help=f"number of the first session (seed {SEED} + this)")
    parser.add_argument("--start-views", type=int, default=START_VIEWS,
                        help="shared random views each session starts from (earlier runs "
                        "started from 3)")
    parser.add_argument("--json", type=Path, help="write every session's figures here")
    parser.add_argument("--merge", type=Path, nargs="+", metavar="JSON",
                        help="print the tables of runs written by --json (e.g. one per case, "
                        "run at once) instead of running")
    args = parser.parse_args(argv)
    cases = ("webcam",) if args.quick else tuple(args.cases.split(","))
    sessions = 2 if args.quick else args.sessions
    max_views = 8 if args.quick else args.max_views
    start = time.perf_counter()
    if args.merge:
        result = merged(args.merge)
        sessions, max_views = result["sessions"], result["max_views"]
    else:
        json_path = args.json

        def save(partial: dict[str, Any]) -> None:
            if json_path is not None:
                json_path.write_text(json.dumps(partial, indent=1))
        result = run(cases, sessions, max_views, progress=save, first=args.first,
                     start_views=args.start_views)
    print(f"\nviews needed to reach a true projection difference, median of {sessions} "
          f"sessions (at most {max_views} views; {result['start_views']} shared random "
          f"views first, a solve from {SOLVE_VIEWS} views; "
          f"corner noise {NOISE_PX} px)\n")
    print(markdown(result))
    print("\nmedian true projection difference (px) after so many views\n")
    print(markdown_differences(result))
    for label, r in result["cases"].items():
        print(f"\n{label}: next_pose {r['next_pose_s_at_40'] * 1000:.0f} ms at 40 views, "
              f"median {r['next_pose_s_in_sessions'] * 1000:.0f} ms in the guided sessions")
    print(f"\n{time.perf_counter() - start:.0f} s")
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
