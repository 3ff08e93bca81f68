"""The live solve: the current camera and its projection uncertainty, after every new view.

A live stream collects views for minutes; the user needs to know all along how good a
solve of them would be. :class:`LiveSolver` updates an estimate of the intrinsics and
their covariance from the views collected so far, warm-started from the previous update:
the views it solved before keep their poses, a new view's pose comes from the current
camera, and a few Levenberg-Marquardt steps (the poses eliminated, so a step costs one
small dense solve) settle the lot. :class:`LiveSolve` runs it on its own thread ("live
solve"), latest-wins: a collection offered while a solve runs replaces the one waiting,
so an image callback or the overlay never waits for it. With fewer views than a solve needs
it hands the usable views to ``on_early`` instead (guidance before the first solve).

The figures are those of the final solve (:mod:`artcal_ros.core.calibrate.pipeline`): the
same views (the selection of at most ``max_views``), points, weights re-scaled to the
residuals, and the covariance of the free intrinsics from the Jacobian with the poses
eliminated, scaled by the measured residual variance
(:func:`~artcal_ros.core.calibrate.quality.intrinsic_covariance`); the projection
uncertainty is its effect on the image, RMS and max over a grid of the whole image
(:func:`~artcal_ros.core.calibrate.quality.parameter_effect_px`; docs/conventions.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.lm import reweighted
from artcal_ros.core.calibrate.pipeline import max_rms_px
from artcal_ros.core.calibrate.quality import (
    intrinsic_covariance,
    parameter_effect_px,
    solution_camera,
)
from artcal_ros.core.calibrate.solve import (
    Solution,
    SolveOptions,
    ViewPoints,
    bundle_adjust,
    estimate_pose,
    free_parameters,
    residuals,
    solve,
)
from artcal_ros.core.calibrate.views import (
    GeometryCache,
    lens_corrected_centers,
    select_views,
    view_points,
    view_problem,
)
from artcal_ros.core.camera import CameraModel
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError, CalibrationError
from artcal_ros.core.live.background import BackgroundTier

__all__ = ["LiveEstimate", "LiveSolve", "LiveSolveConfig", "LiveSolver"]

MIN_VIEWS = 2  # two differently tilted views fix the focal lengths and principal point
WARM_TOLERANCE = 1e-8  # a warm solve stops once a step gains less than this share
WARM_ITERATIONS = 30
OUTLIER_SIGMAS = 5.0  # as the final solve: robust sigmas, and at least OUTLIER_FLOOR_PX
OUTLIER_FLOOR_PX = 0.5


@dataclass(frozen=True)
class LiveSolveConfig:
    """What the live solve estimates, as the final solve would (``calibrate_kwargs``).

    Attributes:
        model: the lens model; points: ``corners`` | ``centers``.
        options: what the solve holds fixed.
        max_views: the views solved at most (the same selection as the final solve).
    """

    model: str = "plumb_bob"
    points: str = "corners"
    options: SolveOptions = field(default_factory=SolveOptions)
    max_views: int = 40

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> LiveSolveConfig:
        """From validated flat parameters (``camera_model``, ``points``, ``max_views``, the
        ``calibrate.*`` options), as the final solve reads them."""
        return cls(str(params["camera_model"]), str(params["points"]),
                   SolveOptions(int(params["calibrate.k_coefficients"]),
                                bool(params["calibrate.fix_principal_point"]),
                                bool(params["calibrate.fix_aspect_ratio"]),
                                bool(params["calibrate.zero_tangent_dist"])),
                   int(params["max_views"]))


@dataclass(frozen=True)
class LiveEstimate:
    """One update of the live solve.

    Attributes:
        views: the views solved (positions ``ViewPoints.index`` in the collection), with
            the sigmas the solve weighted them by; ``solution`` their intrinsics and poses.
        camera: the solved camera; image_size: (width, height), pixels.
        covariance: (p, p) of the free intrinsics, order of ``solution.free``.
        uncertainty_rms_px, uncertainty_max_px: 1-sigma projection uncertainty, RMS and max
            over the whole image, pixels.
        reprojection_rms_px: the fit's RMS residual, pixels.
        collected: views in the collection this update solved from (``views`` may be
            fewer: unusable views and those beyond ``max_views`` are left out).
        seconds: wall time of the update; warm: started from the previous update.
        finished: ``time.monotonic()`` when it finished.
    """

    views: list[ViewPoints]
    solution: Solution
    camera: CameraModel
    image_size: tuple[int, int]
    covariance: np.ndarray
    uncertainty_rms_px: float
    uncertainty_max_px: float
    reprojection_rms_px: float
    collected: int
    seconds: float
    warm: bool
    finished: float

    @property
    def n_views(self) -> int:
        """Views in the solve."""
        return len(self.views)

    @property
    def weighted(self) -> bool:
        """Whether the solve weighted points by their sigmas."""
        return any(v.sigma_px is not None and bool(np.isfinite(v.sigma_px).any())
                   for v in self.views)


class LiveSolver:
    """Updates the estimate from a growing collection (one thread at a time; no locking).

    Args:
        board: the calibration board.
        config: model, points, options, max_views.
    """

    def __init__(self, board: Board, config: LiveSolveConfig | None = None) -> None:
        self.board = board
        self.config = config or LiveSolveConfig()
        self._geometry = GeometryCache()
        self._clear()

    def _clear(self) -> None:
        self._dets: list[Detections] = []
        self._points: list[ViewPoints | None] = []  # per collected view; None: unusable
        self._size: tuple[int, int] | None = None
        self._poses: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._last: Solution | None = None
        self._early: list[ViewPoints] = []

    @property
    def early_views(self) -> list[ViewPoints]:
        """The usable views of the last update when they were too few to solve (else
        empty)."""
        return list(self._early)

    def update(self, collection: Sequence[Detections],
               image_size: tuple[int, int]) -> LiveEstimate | None:
        """Solve the collection (oldest view first); None with fewer than MIN_VIEWS usable views.

        Raises:
            CalibrationError: the views cannot be solved (the next update starts cold).
        """
        start = time.monotonic()
        self._follow(collection, image_size)
        usable = [v for v in self._points if v is not None]
        self._early = usable if len(usable) < MIN_VIEWS else []
        if len(usable) < MIN_VIEWS:
            return None
        cfg = self.config
        if len(usable) > cfg.max_views:
            keep = select_views(usable, image_size, cfg.max_views, cache=self._geometry)
            usable = [usable[k] for k in keep]
        warm = self._last is not None
        try:
            sol, views, res = self._solve(usable, image_size, warm)
            problem = _implausible(sol, res, image_size)
            if problem and warm:  # the previous estimate led astray: start again
                warm = False
                sol, views, res = self._solve(usable, image_size, warm)
                problem = _implausible(sol, res, image_size)
            if problem:
                raise CalibrationError(f"{len(usable)} views: {problem}")
            weighted = any(v.sigma_px is not None and np.isfinite(v.sigma_px).any()
                           for v in views)
            cov, _ = intrinsic_covariance(views, sol, res, weighted=weighted, by_marker=True)
            _, unc_rms, unc_max = parameter_effect_px(sol, image_size, cov)
        except (ArtcalError, np.linalg.LinAlgError, ValueError):
            self._last = None
            raise
        self._last = sol
        self._poses = {v.index: (r, t) for v, r, t in zip(views, sol.rvecs, sol.tvecs,
                                                          strict=True)}
        r = np.concatenate([np.asarray(x).reshape(-1, 2) for x in res])
        return LiveEstimate(
            views=views, solution=sol, camera=solution_camera(sol, image_size),
            image_size=image_size, covariance=cov, uncertainty_rms_px=unc_rms,
            uncertainty_max_px=unc_max,
            reprojection_rms_px=float(np.sqrt(np.mean(np.sum(r ** 2, axis=1)))),
            collected=len(collection), seconds=time.monotonic() - start, warm=warm,
            finished=time.monotonic())

    def _solve(self, usable: list[ViewPoints], size: tuple[int, int], warm: bool
               ) -> tuple[Solution, list[ViewPoints], list[np.ndarray]]:
        """(solution, the views as solved, their residuals): warm or cold, outlier points
        left out, the weights re-scaled to the residuals."""
        sol, views = self._warm(usable, size) if warm else self._cold(usable, size)
        sol, views = self._without_outliers(sol, views)
        if any(v.sigma_px is not None and np.isfinite(v.sigma_px).any() for v in views):
            views = reweighted(views, residuals(views, sol))
            sol = self._adjust(views, sol, (sol.rvecs, sol.tvecs), weighted=True)
        return sol, views, residuals(views, sol)

    def _follow(self, collection: Sequence[Detections], image_size: tuple[int, int]) -> None:
        """Take the collection's new views; a collection that is not the old one grown
        (a reset, another image size) starts over."""
        same = (self._size == tuple(image_size) and len(collection) >= len(self._dets)
                and all(a is b for a, b in zip(collection, self._dets, strict=False)))
        if not same:
            self._clear()
            self._size = (int(image_size[0]), int(image_size[1]))
        for k in range(len(self._dets), len(collection)):
            det = collection[k]
            v = view_points(det, self.board, self.config.points, k)
            self._dets.append(det)
            self._points.append(v if view_problem(v, self.board) is None else None)

    def _cold(self, views: list[ViewPoints], size: tuple[int, int]
              ) -> tuple[Solution, list[ViewPoints]]:
        cfg = self.config
        weighted = any(v.sigma_px is not None and np.isfinite(v.sigma_px).any() for v in views)
        sol, _ = solve(views, size, cfg.model, options=cfg.options, weighted=weighted)
        if cfg.points == "centers":
            views = [lens_corrected_centers(v, solution_camera(sol, size)) for v in views]
            sol = self._adjust(views, sol, (sol.rvecs, sol.tvecs), weighted=weighted)
        return sol, views

    def _warm(self, views: list[ViewPoints], size: tuple[int, int]
              ) -> tuple[Solution, list[ViewPoints]]:
        last = self._last
        assert last is not None
        if self.config.points == "centers":
            views = [lens_corrected_centers(v, solution_camera(last, size)) for v in views]
        rvecs = np.empty((len(views), 3))
        tvecs = np.empty((len(views), 3))
        for k, v in enumerate(views):
            pose = self._poses.get(v.index)
            if pose is None:
                pose = estimate_pose(v, last.camera_matrix, last.dist_coeffs, last.model)
            rvecs[k], tvecs[k] = pose
        weighted = any(v.sigma_px is not None and np.isfinite(v.sigma_px).any() for v in views)
        return self._adjust(views, last, (rvecs, tvecs), weighted=weighted), views

    def _adjust(self, views: list[ViewPoints], start: Solution,
                poses: tuple[np.ndarray, np.ndarray], *, weighted: bool) -> Solution:
        """A few LM steps from ``start``'s intrinsics and ``poses``."""
        cfg = self.config
        free = free_parameters(cfg.model, options=cfg.options)
        K, D, rv, tv = bundle_adjust(views, start.camera_matrix, start.dist_coeffs, cfg.model,
                                     free=free, weighted=weighted, poses=poses,
                                     max_iterations=WARM_ITERATIONS, tolerance=WARM_TOLERANCE)
        return Solution(K, D, cfg.model, rv, tv, free)

    def _without_outliers(self, sol: Solution, views: list[ViewPoints]
                          ) -> tuple[Solution, list[ViewPoints]]:
        """Points far from their projection left out, and the solve repeated once."""
        res = residuals(views, sol)
        norms = [np.linalg.norm(r, axis=1) for r in res]
        sigma = float(np.median(np.concatenate(norms))) / 1.1774  # Rayleigh median
        thr = max(OUTLIER_SIGMAS * sigma, OUTLIER_FLOOR_PX)
        if all(bool((n <= thr).all()) for n in norms):
            return sol, views
        kept, rows = [], []
        for k, (v, n) in enumerate(zip(views, norms, strict=True)):
            sub = v.subset(n <= thr)
            if view_problem(sub, self.board) is None:
                kept.append(sub)
                rows.append(k)
        if len(kept) < MIN_VIEWS:
            return sol, views
        weighted = any(v.sigma_px is not None and np.isfinite(v.sigma_px).any() for v in kept)
        return self._adjust(kept, sol, (sol.rvecs[rows], sol.tvecs[rows]),
                            weighted=weighted), kept


def _implausible(sol: Solution, res: list[np.ndarray], size: tuple[int, int]) -> str | None:
    """Why a solve cannot be the camera (the final solve's first checks), or None."""
    r = np.concatenate([np.asarray(x).reshape(-1, 2) for x in res])
    rms = float(np.sqrt(np.mean(np.sum(r ** 2, axis=1))))
    K = sol.camera_matrix
    if not rms <= max_rms_px(size):
        return f"the fit leaves {rms:.2f} px RMS (a wrong start or the wrong board or model)"
    if not (0 <= K[0, 2] <= size[0] and 0 <= K[1, 2] <= size[1] and 0.5 < K[0, 0] / K[1, 1] < 2):
        return "the solve's principal point or aspect ratio cannot be right (a wrong start)"
    return None


# The longest a collection offered waits for ``defer_while`` to clear before it is solved.
MAX_DEFER_S = 2.0
# After an update the thread rests this many times as long as the update took before the
# next: at most half of one core, so the precise detection that makes the views keeps its.
REST_FACTOR = 1.0


class LiveSolve(BackgroundTier[tuple[int, list[Detections], tuple[int, int]]]):
    """The live solve on its own thread, "live solve", latest-wins.

    :meth:`offer` hands over the collection (never waits); the thread solves the newest
    collection offered and :meth:`snapshot` gives the last estimate. After each update it
    rests as long as the update took (:data:`REST_FACTOR`). Started on creation;
    :meth:`stop` joins the thread.

    Args:
        board: the calibration board; config: what the solve estimates.
        on_update: called on the thread with each new estimate.
        on_error: called on the thread with an error a solve raised (the estimate stays
            the previous one; the next update starts cold).
        on_early: called on the thread with (the usable views, image size, the
            :attr:`generation` they belong to) when an update has too few views to solve.
        defer_while: while it returns True (frames wait for precise detection) a collection
            offered waits, up to :data:`MAX_DEFER_S`: on two busy cores the solve would
            otherwise take the time that measures the next views. Called with the thread's
            lock held: it must take no lock of its own.
    """

    def __init__(self, board: Board, config: LiveSolveConfig | None = None, *,
                 on_update: Callable[[LiveEstimate], None] | None = None,
                 on_error: Callable[[BaseException], None] | None = None,
                 on_early: Callable[[list[ViewPoints], tuple[int, int], int], None]
                 | None = None,
                 defer_while: Callable[[], bool] | None = None) -> None:
        super().__init__("live solve")
        self._solver = LiveSolver(board, config)
        self._on_update = on_update
        self._on_error = on_error
        self._on_early = on_early
        self._defer_while = defer_while
        self._offered = 0.0  # time.monotonic() of the offer waiting
        self._started = 0.0  # time.monotonic() the running update started
        self._rest_until = 0.0  # no update starts before this
        self._waiting: tuple[int, list[Detections], tuple[int, int]] | None = None
        self._busy = False
        self._estimate: LiveEstimate | None = None
        self._error = ""
        self._start()

    def offer(self, collection: Sequence[Detections], image_size: tuple[int, int]) -> None:
        """Solve this collection next (replacing one still waiting)."""
        with self._cond:
            if self._waiting is None:
                self._offered = time.monotonic()
            self._waiting = (self._generation, list(collection), image_size)
            self._cond.notify_all()

    def set_config(self, config: LiveSolveConfig) -> None:
        """Solve with other options from the next update on (a fresh, cold start)."""
        with self._commit:
            self._generation += 1
            self._solver = LiveSolver(self._solver.board, config)
            self._estimate = None

    @property
    def config(self) -> LiveSolveConfig:
        """What the solve estimates now."""
        with self._commit:
            return self._solver.config

    @property
    def generation(self) -> int:
        """Counts resets and new configurations: what ``on_early`` got is stale once this
        differs from the generation it was given."""
        with self._commit:
            return self._generation

    def snapshot(self) -> LiveEstimate | None:
        """The last estimate (None before the first, and after a reset)."""
        with self._cond:
            return self._estimate

    @property
    def error(self) -> str:
        """Why the last update failed ("" when it did not)."""
        with self._cond:
            return self._error

    @property
    def busy(self) -> bool:
        """Whether a collection waits or is being solved."""
        with self._cond:
            return self._busy or self._waiting is not None

    def reset(self) -> None:
        """Forget the estimate; an update in flight adds nothing."""
        with self._commit, self._cond:
            self._generation += 1
            self._waiting = None
            self._estimate = None
            self._error = ""

    def _next_job(self) -> tuple[int, list[Detections], tuple[int, int]] | None:
        now = time.monotonic()
        if self._waiting is not None and (now < self._rest_until or (
                self._defer_while is not None and now - self._offered < MAX_DEFER_S
                and self._defer_while())):
            return None  # polled again in 50 ms
        job, self._waiting = self._waiting, None
        self._busy = job is not None
        self._started = now
        return job

    def _pending(self) -> int:
        return 0

    def _job_done(self, job: tuple[int, list[Detections], tuple[int, int]]) -> None:
        self._busy = False
        now = time.monotonic()
        self._rest_until = now + REST_FACTOR * (now - self._started)

    def _work(self, job: tuple[int, list[Detections], tuple[int, int]]) -> None:
        generation, collection, size = job
        with self._commit:
            solver = self._solver
            if generation != self._generation:
                return
        try:
            estimate = solver.update(collection, size)
            error = ""
        except Exception as e:  # a failed update keeps the last estimate
            estimate, error = None, str(e)
            self._report(self._on_error, e)
        with self._commit, self._cond:
            if generation != self._generation:
                return
            self._error = error
            if estimate is not None:
                self._estimate = estimate
        if estimate is not None and self._on_update is not None:
            self._on_update(estimate)
        elif estimate is None and not error and self._on_early is not None:
            early = solver.early_views
            if early:
                self._on_early(early, size, generation)

    def stop(self, timeout: float = 1.0) -> bool:
        """End the thread (an update in progress finishes) and wait up to ``timeout`` s;
        whether it ended. Idempotent."""
        return self._stop_thread(timeout)
