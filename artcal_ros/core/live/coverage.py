"""The live collection: which views are new, the coverage they reach, and readiness.

:class:`ViewCollector` keeps the views of a stream that add something (new markers, a new
place in the image, a new tilt), counts their points over the coverage grid for the heat
map, and says what is still missing before a solve (:class:`Readiness`). Every view is
measured with the one view geometry of :mod:`artcal_ros.core.live.view_geometry`, the one the
solve judges by, so the node cannot call a collection "ready" whose solve then warns that
the coverage is poor.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.view_geometry import (
    COVERAGE_GRID,
    MIN_COVERAGE,
    REGION_NAMES,
    ViewGeometry,
    coverage_fraction,
    solve_points,
    view_geometry,
)


@dataclass(frozen=True)
class CoverageConfig:
    """What a collection needs before it is ready, and when a view counts as new.

    The coverage grid and threshold are not here on purpose: they are
    :data:`COVERAGE_GRID` and :data:`MIN_COVERAGE`, the ones the solve judges by.

    Attributes:
        min_views: views needed before a solve is attempted.
        min_markers: markers a view needs to be kept.
        points: ``corners`` | ``centers``: the points the solve will use (coverage is
            counted on them, as the solve counts it).
        tilt_deg: a view is "tilted" about an axis beyond this angle, degrees.
        novelty: a view is new unless some kept view shares at least half of its markers,
            their mean displacement is within this fraction of the image diagonal, and
            the board's tilt differs by at most half of ``tilt_deg``.
        max_stored: views kept at most; later views are counted but not stored.
    """

    min_views: int = 10
    min_markers: int = 6
    points: str = "corners"
    tilt_deg: float = 15.0
    novelty: float = 0.03
    max_stored: int = 400


@dataclass(frozen=True)
class Readiness:
    """How far a collection is from a good solve.

    Attributes:
        views: views kept so far; views_needed: ``min_views``.
        coverage: fraction (0..1) of grid cells with a board point; coverage_needed likewise.
        tilted_lr, tilted_ud: kept views tilted left/right and up/down.
        missing: plain-language items still missing (empty when ready).
    """

    views: int
    views_needed: int
    coverage: float
    coverage_needed: float
    tilted_lr: int
    tilted_ud: int
    missing: tuple[str, ...]

    @property
    def enough_views(self) -> bool:
        """Whether a solve may be attempted (the hard requirement)."""
        return self.views >= self.views_needed

    @property
    def ready(self) -> bool:
        """Whether nothing is missing."""
        return not self.missing

    def summary(self) -> str:
        """One line: views, coverage, and what is missing."""
        head = (f"views {self.views}/{self.views_needed}, coverage {self.coverage:.0%} "
                f"(want {self.coverage_needed:.0%}), tilted views {self.tilted_lr} left/right "
                f"{self.tilted_ud} up/down")
        return head + ("; ready" if self.ready else "; missing: " + "; ".join(self.missing))


@dataclass(frozen=True)
class Snapshot:
    """One consistent look at a collection (taken under its lock).

    Attributes:
        views: the kept views, oldest first (a new list).
        image_size: (width, height) of the views, pixels; None before the first.
        counts: (rows, cols) int64, how many kept views put a point in each grid cell.
        readiness: views, coverage, tilt and what is missing.
    """

    views: list[Detections]
    image_size: tuple[int, int] | None
    counts: np.ndarray
    readiness: Readiness


class ViewCollector:
    """Keeps the views worth solving from and the coverage they add (thread-safe).

    Every read and change of the collection happens under one lock, so views, image
    size, counts and readiness always describe the same collection, whichever threads
    add, reset and query at once.

    Args:
        board: the calibration board.
        config: thresholds (see :class:`CoverageConfig`).
    """

    def __init__(self, board: Board, config: CoverageConfig | None = None) -> None:
        self.board = board
        self._config = config or CoverageConfig()
        self._lock = threading.Lock()
        self._views: list[Detections] = []
        self._geometry: list[ViewGeometry] = []
        gx, gy = COVERAGE_GRID
        self._counts = np.zeros((gy, gx), np.int64)
        self._image_size: tuple[int, int] | None = None
        # views taken on approximate markers, waiting for their precise detection
        self._pending: dict[int, tuple[Detections, ViewGeometry]] = {}
        self._next_ticket = 1

    @property
    def config(self) -> CoverageConfig:
        """The thresholds; setting them applies to later views and queries."""
        with self._lock:
            return self._config

    @config.setter
    def config(self, config: CoverageConfig) -> None:
        with self._lock:
            self._config = config

    def reset(self) -> int:
        """Forget every view and the coverage; the number of views forgotten."""
        with self._lock:
            n = len(self._views)
            self._clear()
            return n

    def _clear(self) -> None:
        # Caller holds the lock.
        self._views = []
        self._geometry = []
        self._counts = np.zeros_like(self._counts)
        self._image_size = None
        self._pending = {}

    # --- accumulation -------------------------------------------------------------
    def _is_new(self, dets: Detections, geometry: ViewGeometry, cfg: CoverageConfig) -> bool:
        # Caller holds the lock. Against every kept view, not just the last: a board held
        # still, or a recording played in a loop, must not fill the collection with copies
        # of one view.
        w, h = dets.image_size
        ids, pos = view_marks(self.board, dets)
        others = [*zip(reversed(self._views), reversed(self._geometry), strict=True),
                  *self._pending.values()]
        for old, old_geometry in others:
            old_ids, old_pos = view_marks(self.board, old)
            if same_view(ids, pos, geometry, old_ids, old_pos, old_geometry,
                         cfg.novelty * math.hypot(w, h), 0.5 * cfg.tilt_deg):
                return False
        return True

    def _too_few(self, dets: Detections, *, tracked: bool = False) -> bool:
        return not measures_board(self.board, dets, self.config.min_markers, tracked=tracked)

    def _geometry_of(self, dets: Detections, cfg: CoverageConfig
                     ) -> tuple[tuple[int, int], ViewGeometry]:
        # The pose costs a PnP solve: callers run it outside the lock (it depends on this
        # view only).
        size = (int(dets.image_size[0]), int(dets.image_size[1]))
        return size, view_geometry(*solve_points(dets, self.board, cfg.points), size)

    def add(self, dets: Detections) -> bool:
        """Offer one view; return whether it was kept (enough markers, new, room left).

        A view of another image size than the kept ones starts a fresh collection,
        since views of different sizes cannot be solved together.
        """
        cfg = self.config
        if self._too_few(dets):
            return False
        size, geometry = self._geometry_of(dets, cfg)
        with self._lock:
            # The size test, the reset and the append are one step: a reset or a view of
            # another size coming in between must not leave views of two sizes together.
            if self._image_size is not None and size != self._image_size:
                self._clear()
            if len(self._views) >= cfg.max_stored or not self._is_new(dets, geometry, cfg):
                return False
            self._image_size = size
            self._views.append(dets)
            self._geometry.append(geometry)
            self._counts += geometry.cells.reshape(self._counts.shape)
            return True

    def reserve(self, dets: Detections) -> int | None:
        """Hold a place for a view seen on approximate markers; a ticket, or None if not new.

        A live stream finds the markers of every frame approximately (tracked) and only
        some precisely. A frame whose approximate markers would make a new view is held
        here until :meth:`settle` brings its precise detections, so the frames after it
        that show the same view are not measured again. A held view counts as a view for
        novelty only: not in :meth:`snapshot`, the readiness or the coverage.
        """
        cfg = self.config
        if self._too_few(dets, tracked=True):
            return None
        _, geometry = self._geometry_of(dets, cfg)
        with self._lock:
            if len(self._views) + len(self._pending) >= cfg.max_stored \
                    or not self._is_new(dets, geometry, cfg):
                return None
            ticket = self._next_ticket
            self._next_ticket += 1
            self._pending[ticket] = (dets, geometry)
            return ticket

    def settle(self, ticket: int, dets: Detections) -> bool:
        """Replace a held view by its precise detections; whether they were kept.

        They are offered as :meth:`add` does. A ticket no longer held (a reset came in
        between) keeps nothing.
        """
        with self._lock:
            if self._pending.pop(ticket, None) is None:
                return False
        return self.add(dets)

    def release(self, ticket: int) -> None:
        """Give up a held view (its precise detection failed or was never made)."""
        with self._lock:
            self._pending.pop(ticket, None)

    @property
    def pending(self) -> int:
        """Views held by :meth:`reserve` and not yet settled."""
        with self._lock:
            return len(self._pending)

    # --- queries ------------------------------------------------------------------
    @property
    def views(self) -> list[Detections]:
        """A copy of the kept views, oldest first."""
        with self._lock:
            return list(self._views)

    @property
    def image_size(self) -> tuple[int, int] | None:
        """(width, height) of the kept views, pixels; None before the first."""
        with self._lock:
            return self._image_size

    def counts(self) -> np.ndarray:
        """(rows, cols) int64 over :data:`COVERAGE_GRID`: kept views with a point in each cell."""
        with self._lock:
            return self._counts.copy()

    def coverage(self) -> float:
        """Fraction (0..1) of grid cells holding a point of some kept view."""
        with self._lock:
            return coverage_fraction(self._counts.reshape(-1) > 0)

    def readiness(self) -> Readiness:
        """Views, coverage and tilt so far, and what is missing, in words."""
        return self.snapshot().readiness

    def snapshot(self) -> Snapshot:
        """Views, image size, counts and readiness of one and the same collection."""
        with self._lock:
            cfg = self._config
            views = list(self._views)
            size = self._image_size
            counts = self._counts.copy()
            lr = sum(abs(g.tilt_x_deg) > cfg.tilt_deg for g in self._geometry)
            ud = sum(abs(g.tilt_y_deg) > cfg.tilt_deg for g in self._geometry)
        return Snapshot(views, size, counts, _readiness(cfg, len(views), counts, lr, ud))


def _readiness(cfg: CoverageConfig, n: int, counts: np.ndarray, lr: int, ud: int) -> Readiness:
    """What is missing, given the views kept, their cell counts and tilted views."""
    covered = coverage_fraction(counts.reshape(-1) > 0)
    missing: list[str] = []
    if n < cfg.min_views:
        missing.append(count_text(cfg.min_views - n, "more view"))
    if covered < MIN_COVERAGE:
        empty = empty_regions(counts)
        where = f" (nothing yet at {', '.join(empty)})" if empty else ""
        missing.append(f"coverage {covered:.0%} of {MIN_COVERAGE:.0%}{where}")
    if lr < 2:
        missing.append(f"{count_text(2 - lr, 'view')} with the board turned left or right "
                       f"by more than {cfg.tilt_deg:g} deg")
    if ud < 2:
        missing.append(f"{count_text(2 - ud, 'view')} with the board tipped up or down "
                       f"by more than {cfg.tilt_deg:g} deg")
    return Readiness(n, cfg.min_views, covered, MIN_COVERAGE, lr, ud, tuple(missing))


def count_text(n: int, noun: str) -> str:
    """``1 view``, ``2 views``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


def measures_board(board: Board, dets: Detections, min_markers: int, *,
                   tracked: bool = False) -> bool:
    """Whether one image's detections measure ``board``: ``min_markers`` markers, or for a
    board with points that many points and at least 8.

    A tracked view (``tracked``, approximate) has the markers only, which stand for the
    points of a ChArUco board until the precise detection comes.
    """
    if board.has_points and not (tracked and board.n_markers):
        return len(dets.point_ids) >= max(min_markers, 8)
    return len(dets) >= min_markers


def view_marks(board: Board, dets: Detections) -> tuple[np.ndarray, np.ndarray]:
    """(ids (N,), image positions (N, 2) px) of what identifies a view: its marker centres
    (marker grids, and ChArUco boards, whose tracked views have markers only), else points."""
    if board.n_markers:
        return dets.ids, dets.centers_px
    return dets.point_ids, dets.points_px


def same_view(ids: np.ndarray, positions: np.ndarray, geometry: ViewGeometry,
              old_ids: np.ndarray, old_positions: np.ndarray, old_geometry: ViewGeometry,
              limit_px: float, turn_deg: float) -> bool:
    """Whether a view (:func:`view_marks` and geometry) repeats an older one: half its marks
    or more seen there, moved ``limit_px`` on average at most and turned ``turn_deg`` at
    most about either axis. Turning the board about its centre barely moves the marks on
    average but is exactly the view a solve needs, hence the tilt test as well."""
    shared, i_new, i_old = np.intersect1d(ids, old_ids, return_indices=True)
    if len(shared) < 0.5 * len(ids):
        return False
    moved = np.linalg.norm(positions[i_new] - old_positions[i_old], axis=1)
    turned = max(abs(geometry.tilt_x_deg - old_geometry.tilt_x_deg),
                 abs(geometry.tilt_y_deg - old_geometry.tilt_y_deg))
    return bool(moved.mean() <= limit_px and turned <= turn_deg)


def empty_regions(counts: np.ndarray) -> list[str]:
    """Names of the 3 x 3 image regions (see REGION_NAMES) whose cells are mostly empty.

    Args:
        counts: (rows, cols) coverage counts, rows >= 3 and cols >= 3.
    """
    rows, cols = counts.shape
    out = []
    for k, name in enumerate(REGION_NAMES):
        i, j = divmod(k, 3)
        block = counts[i * rows // 3:(i + 1) * rows // 3, j * cols // 3:(j + 1) * cols // 3]
        if block.size and (block > 0).mean() < 0.5:
            out.append(name)
    return out

