"""Accumulated coverage of the image and readiness for a solve (what is still missing).

A live calibration needs views that, together, put board points over the whole
image (so distortion is constrained out to the edges) and that tilt the board
(a fronto-parallel plane leaves the focal length unobservable). The
:class:`ViewCollector` keeps the views worth solving from (a new view must
differ from every one kept), counts where their points fall on a coarse
grid, estimates each view's tilt, and says in plain words what is missing.

The tilt estimate assumes a rough camera (focal length = image width,
principal point at the centre): it only decides "tilted or not" for guidance,
so a focal length off by half still sorts views correctly.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections

# Names of the 3 x 3 regions of the image, row-major, for "what is missing".
REGION_NAMES = ("top-left", "top", "top-right", "left", "centre", "right",
                "bottom-left", "bottom", "bottom-right")


@dataclass(frozen=True)
class CoverageConfig:
    """What a collection needs before it is ready, and when a view counts as new.

    Attributes:
        min_views: views needed before a solve is attempted.
        min_markers: markers a view needs to be kept.
        grid_cols, grid_rows: cells of the coverage grid over the image.
        min_coverage: fraction (0..1) of grid cells that should hold a board point.
        tilt_deg: a view is "tilted" about an axis beyond this angle, degrees.
        novelty: a view is new unless some kept view shares at least half of its markers,
            their mean displacement is within this fraction of the image diagonal, and
            the board's tilt differs by at most half of ``tilt_deg``.
        max_stored: views kept at most; later views are counted but not stored.
    """

    min_views: int = 10
    min_markers: int = 6
    grid_cols: int = 12
    grid_rows: int = 9
    min_coverage: float = 0.6
    tilt_deg: float = 15.0
    novelty: float = 0.03
    max_stored: int = 400


@dataclass(frozen=True)
class ViewGeometry:
    """Where one view's board sits: tilt about the image axes and apparent size.

    Attributes:
        tilt_x_deg: rotation of the board about the image's vertical axis (left/right), degrees.
        tilt_y_deg: rotation about the image's horizontal axis (up/down), degrees.
        area_fraction: area of the detected markers' hull over the image area (0..1).
    """

    tilt_x_deg: float
    tilt_y_deg: float
    area_fraction: float


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


def view_geometry(dets: Detections, board: Board) -> ViewGeometry:
    """Estimate a view's tilt and apparent size from its marker centres.

    Args:
        dets: the view's detections (at least 4 markers for a tilt; fewer give zero tilt).
        board: the board the ids belong to.
    """
    w, h = dets.image_size
    pts = dets.corners_px.reshape(-1, 2).astype(np.float32)
    area = float(cv2.contourArea(cv2.convexHull(pts))) / float(w * h) if len(pts) >= 3 else 0.0
    if len(dets) < 4:
        return ViewGeometry(0.0, 0.0, area)
    obj = board.object_centers(dets.ids)[:, :2]
    H, _ = cv2.findHomography(obj, dets.centers_px, 0)
    if H is None:
        return ViewGeometry(0.0, 0.0, area)
    f = float(w)
    K_inv = np.array([[1 / f, 0, -0.5 * (w - 1) / f], [0, 1 / f, -0.5 * (h - 1) / f], [0, 0, 1]])
    M = K_inv @ H
    r1 = M[:, 0] / np.linalg.norm(M[:, 0])
    r2 = M[:, 1] / np.linalg.norm(M[:, 1])
    normal = np.cross(r1, r2)
    normal /= np.linalg.norm(normal)
    if normal[2] < 0:
        normal = -normal
    return ViewGeometry(math.degrees(math.atan2(normal[0], normal[2])),
                        math.degrees(math.atan2(normal[1], normal[2])), area)


class ViewCollector:
    """Keeps the views worth solving from and the coverage they add (thread-safe).

    Args:
        board: the calibration board.
        config: thresholds (see :class:`CoverageConfig`).
    """

    def __init__(self, board: Board, config: CoverageConfig | None = None) -> None:
        self.board = board
        self.config = config or CoverageConfig()
        self._lock = threading.Lock()
        self.reset()

    def reset(self) -> None:
        """Forget every view and the coverage."""
        with self._lock:
            self._views: list[Detections] = []
            self._geometry: list[ViewGeometry] = []
            self._counts = np.zeros((self.config.grid_rows, self.config.grid_cols), np.int64)
            self._image_size: tuple[int, int] | None = None

    # --- accumulation -------------------------------------------------------------
    def _is_new(self, dets: Detections, geometry: ViewGeometry) -> bool:
        # Against every kept view, not just the last: a board held still, or a recording
        # played in a loop, must not fill the collection with copies of one view. Turning
        # the board about its centre barely moves the markers on average but is exactly the
        # view a solve needs, hence the tilt test as well.
        w, h = dets.image_size
        limit = self.config.novelty * math.hypot(w, h)
        turn = 0.5 * self.config.tilt_deg
        for old, old_geometry in zip(reversed(self._views), reversed(self._geometry),
                                     strict=True):
            shared, i_new, i_old = np.intersect1d(dets.ids, old.ids, return_indices=True)
            if len(shared) < 0.5 * len(dets):
                continue
            moved = np.linalg.norm(dets.centers_px[i_new] - old.centers_px[i_old], axis=1)
            turned = max(abs(geometry.tilt_x_deg - old_geometry.tilt_x_deg),
                         abs(geometry.tilt_y_deg - old_geometry.tilt_y_deg))
            if moved.mean() <= limit and turned <= turn:
                return False
        return True

    def add(self, dets: Detections) -> bool:
        """Offer one view; return whether it was kept (enough markers, new, room left).

        A view of another image size than the kept ones starts a fresh collection,
        since views of different sizes cannot be solved together.
        """
        if len(dets) < self.config.min_markers:
            return False
        if self._image_size is not None and tuple(dets.image_size) != self._image_size:
            self.reset()
        geometry = view_geometry(dets, self.board)
        with self._lock:
            if len(self._views) >= self.config.max_stored or not self._is_new(dets, geometry):
                return False
            self._image_size = (int(dets.image_size[0]), int(dets.image_size[1]))
            self._views.append(dets)
            self._geometry.append(geometry)
            self._counts += self._cell_counts(dets)
            return True

    def _cell_counts(self, dets: Detections) -> np.ndarray:
        w, h = dets.image_size
        rows, cols = self.config.grid_rows, self.config.grid_cols
        pts = dets.corners_px.reshape(-1, 2)
        c = np.clip((pts[:, 0] + 0.5) * cols / w, 0, cols - 1).astype(np.int64)
        r = np.clip((pts[:, 1] + 0.5) * rows / h, 0, rows - 1).astype(np.int64)
        counts = np.zeros((rows, cols), np.int64)
        # One count per view and cell: a view crowding one cell is still one view there.
        counts[r, c] = 1
        return counts

    # --- queries ------------------------------------------------------------------
    @property
    def views(self) -> list[Detections]:
        """A copy of the kept views, oldest first."""
        with self._lock:
            return list(self._views)

    @property
    def image_size(self) -> tuple[int, int] | None:
        """(width, height) of the kept views, pixels; None before the first."""
        return self._image_size

    def counts(self) -> np.ndarray:
        """(grid_rows, grid_cols) int64: how many kept views put a point in each cell."""
        with self._lock:
            return self._counts.copy()

    def coverage(self) -> float:
        """Fraction (0..1) of grid cells holding a point of some kept view."""
        with self._lock:
            return float((self._counts > 0).mean())

    def readiness(self) -> Readiness:
        """Views, coverage and tilt so far, and what is missing, in words."""
        cfg = self.config
        with self._lock:
            n = len(self._views)
            counts = self._counts.copy()
            lr = sum(abs(g.tilt_x_deg) > cfg.tilt_deg for g in self._geometry)
            ud = sum(abs(g.tilt_y_deg) > cfg.tilt_deg for g in self._geometry)
        covered = float((counts > 0).mean())
        missing: list[str] = []
        if n < cfg.min_views:
            missing.append(_count(cfg.min_views - n, "more view"))
        if covered < cfg.min_coverage:
            empty = empty_regions(counts)
            where = f" (nothing yet at {', '.join(empty)})" if empty else ""
            missing.append(f"coverage {covered:.0%} of {cfg.min_coverage:.0%}{where}")
        if lr < 2:
            missing.append(f"{_count(2 - lr, 'view')} with the board turned left or right "
                           f"by more than {cfg.tilt_deg:g} deg")
        if ud < 2:
            missing.append(f"{_count(2 - ud, 'view')} with the board tipped up or down "
                           f"by more than {cfg.tilt_deg:g} deg")
        return Readiness(n, cfg.min_views, covered, cfg.min_coverage, lr, ud, tuple(missing))


def _count(n: int, noun: str) -> str:
    """``1 view``, ``2 views``."""
    return f"{n} {noun}" if n == 1 else f"{n} {noun}s"


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
