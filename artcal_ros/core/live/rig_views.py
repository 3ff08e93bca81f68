"""A rig's live collection: the rig views worth solving from, coverage per camera, connectivity.

A rig view is a rig frame in which at least two cameras measure the board (each its own
markers or points; they need not be the same ones). :class:`RigViews` keeps the rig views
that add something for at least one of their cameras (new markers, a new place in its
image, a new tilt: the test :class:`~artcal_ros.core.live.coverage.ViewCollector` applies to
one camera), counts each camera's coverage with the one view geometry of
:mod:`~artcal_ros.core.live.view_geometry`, and says which cameras share too few views with
the others to be solved with them (``rig_start.connectivity_problem``).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.rig_start import (
    MIN_SHARED_FRAMES,
    connectivity_problem,
    shared_frame_counts,
    spanning_tree,
)
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.coverage import Readiness, measures_board, same_view, view_marks
from artcal_ros.core.live.view_geometry import (
    COVERAGE_GRID,
    MIN_COVERAGE,
    ViewGeometry,
    coverage_fraction,
    solve_points,
    view_geometry,
)

__all__ = ["RigSnapshot", "RigView", "RigViews", "RigViewsConfig"]

Frame = Mapping[str, Detections | None]


@dataclass(frozen=True)
class RigViewsConfig:
    """When a rig collection is ready, and when a rig view counts as new.

    Attributes:
        min_views: rig views needed before a solve is attempted.
        max_views: rig views kept at most.
        min_markers: markers (points: ``max(min_markers, 8)``) a camera needs in a frame to
            measure the board in it.
        points: ``corners`` | ``centers``, the points the solve uses.
        tilt_deg, novelty: as :class:`~artcal_ros.core.live.coverage.CoverageConfig`'s.
    """

    min_views: int = 10
    max_views: int = 40
    min_markers: int = 6
    points: str = "corners"
    tilt_deg: float = 15.0
    novelty: float = 0.03


@dataclass(frozen=True)
class RigView:
    """One kept rig view.

    Attributes:
        detections: camera -> its precise detections (None: no image or nothing read).
        measured: the cameras that measure the board in it (two or more).
    """

    detections: dict[str, Detections | None]
    measured: tuple[str, ...]


@dataclass(frozen=True)
class RigSnapshot:
    """One consistent look at a rig collection.

    Attributes:
        names: the cameras, the first the reference.
        views: the kept rig views, oldest first.
        image_sizes: camera -> (width, height) pixels, for the cameras seen so far.
        counts: camera -> (rows, cols) int64 coverage counts of its measured views.
        readiness: camera -> its views, coverage and tilts (``views_needed``: the rig's).
        shared: (a, b) -> rig views both measure the board in, a before b in ``names``.
        not_connected: the cameras sharing too few views with the others (to be solved).
        problem: the connectivity problem in words (None: every camera connected).
        min_views: rig views needed.
    """

    names: tuple[str, ...]
    views: list[RigView]
    image_sizes: dict[str, tuple[int, int]]
    counts: dict[str, np.ndarray]
    readiness: dict[str, Readiness]
    shared: dict[tuple[str, str], int]
    not_connected: tuple[str, ...]
    problem: str | None
    min_views: int

    @property
    def enough(self) -> bool:
        """Enough rig views, every camera connected and seen: a solve may be attempted."""
        return (len(self.views) >= self.min_views and self.problem is None
                and len(self.image_sizes) == len(self.names))

    def detections(self) -> dict[str, list[Detections | None]]:
        """camera -> one entry per kept rig view (the input of ``calibrate_rig``)."""
        return {n: [v.detections.get(n) for v in self.views] for n in self.names}

    def missing(self) -> list[str]:
        """What the collection lacks before a solve, in words (empty: nothing)."""
        missing = []
        if len(self.views) < self.min_views:
            missing.append(f"{self.min_views - len(self.views)} more rig views (the board "
                           "seen by two or more cameras at once)")
        unseen = [n for n in self.names if n not in self.image_sizes]
        if unseen:
            missing.append(f"no image yet from {', '.join(unseen)}")
        if self.problem:
            missing.append(self.problem)
        return missing

    def summary(self) -> str:
        """One line: rig views, shared views per pair, what is missing."""
        pairs = ", ".join(f"{a}-{b} {n}" for (a, b), n in self.shared.items())
        text = f"rig views {len(self.views)}/{self.min_views} (shared views {pairs})"
        missing = self.missing()
        return text + ("; ready" if not missing else "; missing: " + "; ".join(missing))


@dataclass(frozen=True)
class _Seen:
    # what identifies one camera's part of a view, for novelty
    ids: np.ndarray
    positions: np.ndarray
    geometry: ViewGeometry


class RigViews:
    """The rig views of a live rig (thread-safe: every read and change holds one lock).

    Args:
        board: the calibration board.
        names: the cameras, the first the reference.
        config: thresholds, see :class:`RigViewsConfig`.
    """

    def __init__(self, board: Board, names: Sequence[str],
                 config: RigViewsConfig | None = None) -> None:
        self.board = board
        self.names = tuple(names)
        self.config = config or RigViewsConfig()
        self._lock = threading.Lock()
        self._views: list[RigView] = []
        self._seen: list[dict[str, _Seen]] = []
        self._pending: dict[int, dict[str, _Seen]] = {}
        self._sizes: dict[str, tuple[int, int]] = {}
        self._next_ticket = 1

    def measures(self, dets: Detections | None, *, tracked: bool = False) -> bool:
        """Whether one camera's detections measure the board (enough markers or points;
        tracked ones have markers only, which stand for the points)."""
        if dets is None:
            return False
        return measures_board(self.board, dets, self.config.min_markers, tracked=tracked)

    def _features(self, dets: Detections) -> _Seen:
        # Outside the lock: the pose is a PnP solve of this camera's view only.
        size = (int(dets.image_size[0]), int(dets.image_size[1]))
        geometry = view_geometry(*solve_points(dets, self.board, self.config.points), size)
        return _Seen(*view_marks(self.board, dets), geometry)

    def _parts(self, frame: Frame, tracked: bool) -> dict[str, _Seen]:
        return {n: self._features(d) for n, d in frame.items()
                if n in self.names and d is not None and self.measures(d, tracked=tracked)}

    def _similar(self, new: _Seen, old: _Seen, size: tuple[int, int]) -> bool:
        return same_view(new.ids, new.positions, new.geometry, old.ids, old.positions,
                         old.geometry, self.config.novelty * math.hypot(*size),
                         0.5 * self.config.tilt_deg)

    def _is_new(self, parts: dict[str, _Seen], frame: Frame) -> bool:
        # Caller holds the lock. New when some camera's part is like none of that camera's
        # kept or held parts.
        others = [*self._seen, *self._pending.values()]
        for n, part in parts.items():
            dets = frame[n]
            assert dets is not None
            size = (int(dets.image_size[0]), int(dets.image_size[1]))
            if not any(n in o and self._similar(part, o[n], size) for o in others):
                return True
        return False

    def hold(self, tracked: Frame) -> int | None:
        """Hold a place for a rig frame seen on tracked markers; a ticket, or None when it
        is no new rig view (fewer than two cameras see the board, nothing new, or full).
        A held view counts for novelty only, until :meth:`settle` or :meth:`release`."""
        parts = self._parts(tracked, tracked=True)
        if len(parts) < 2:
            return None
        with self._lock:
            if len(self._views) + len(self._pending) >= self.config.max_views \
                    or not self._is_new(parts, tracked):
                return None
            ticket = self._next_ticket
            self._next_ticket += 1
            self._pending[ticket] = parts
            return ticket

    def release(self, ticket: int) -> None:
        """Give up a held view."""
        with self._lock:
            self._pending.pop(ticket, None)

    def settle(self, ticket: int, measured: Frame) -> bool:
        """Replace a held view by its precise detections; whether they were kept."""
        with self._lock:
            if self._pending.pop(ticket, None) is None:
                return False  # a reset came in between
        return self.add(measured)

    def add(self, measured: Frame) -> bool:
        """Offer a rig frame's precise detections; whether it was kept as a rig view.

        A camera's image of another size than its earlier ones starts a fresh collection
        (views of different sizes cannot be solved together).
        """
        parts = self._parts(measured, tracked=False)
        if len(parts) < 2:
            return False
        sizes = {n: (int(d.image_size[0]), int(d.image_size[1]))
                 for n, d in measured.items() if d is not None and n in self.names}
        with self._lock:
            if any(self._sizes.get(n, s) != s for n, s in sizes.items()):
                self._clear()
            if len(self._views) >= self.config.max_views or not self._is_new(parts, measured):
                return False
            self._sizes.update(sizes)
            self._views.append(RigView({n: measured.get(n) for n in self.names},
                                       tuple(n for n in self.names if n in parts)))
            self._seen.append(parts)
            return True

    def note_size(self, name: str, size: tuple[int, int]) -> None:
        """A camera's image size, known from its stream before any view."""
        with self._lock:
            if self._sizes.get(name, size) != size:
                self._clear()
            self._sizes[name] = size

    @property
    def pending(self) -> int:
        """Views held and not yet settled."""
        with self._lock:
            return len(self._pending)

    def reset(self) -> int:
        """Forget every view; the number of rig views forgotten."""
        with self._lock:
            n = len(self._views)
            self._clear()
            return n

    def _clear(self) -> None:
        self._views, self._seen, self._pending, self._sizes = [], [], {}, {}

    def snapshot(self) -> RigSnapshot:
        """Views, sizes, coverage, readiness and connectivity of one and the same collection."""
        cfg = self.config
        with self._lock:
            views, seen, sizes = list(self._views), list(self._seen), dict(self._sizes)
        gx, gy = COVERAGE_GRID
        counts = {n: np.zeros((gy, gx), np.int64) for n in self.names}
        tilts = {n: [0, 0] for n in self.names}
        for parts in seen:
            for n, part in parts.items():
                counts[n] += part.geometry.cells.reshape(gy, gx)
                tilts[n][0] += abs(part.geometry.tilt_x_deg) > cfg.tilt_deg
                tilts[n][1] += abs(part.geometry.tilt_y_deg) > cfg.tilt_deg
        measured = {n: {i for i, v in enumerate(views) if n in v.measured} for n in self.names}
        shared = shared_frame_counts(self.names, measured)
        problem = connectivity_problem(self.names, shared) if views else None
        tree = spanning_tree(self.names, shared, min_shared=MIN_SHARED_FRAMES)
        reached = {self.names[0], *(b for _, b in tree)}
        apart = tuple(n for n in self.names if n not in reached) if problem else ()
        readiness = {}
        for n in self.names:
            covered = coverage_fraction(counts[n].reshape(-1) > 0)
            missing = []
            if len(views) < cfg.min_views:
                missing.append(f"{cfg.min_views - len(views)} more rig views")
            if n in apart:
                missing.append(f"{n} shares too few views with the other cameras")
            readiness[n] = Readiness(len(measured[n]), cfg.min_views, covered, MIN_COVERAGE,
                                     tilts[n][0], tilts[n][1], tuple(missing))
        return RigSnapshot(self.names, views, sizes, counts, readiness, shared, apart,
                           problem, cfg.min_views)
