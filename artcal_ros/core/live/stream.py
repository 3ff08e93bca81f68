"""Two tiers for a live camera stream: every frame tracked, the useful ones measured.

Precise detection (:class:`~artcal_ros.core.detect.Detector`) takes a few hundred
milliseconds a 1080p frame on a small machine; a camera sends a frame every 33 ms. So a
live stream is handled in two tiers:

1. **Every frame, at once** (:meth:`LiveDetection.offer`, the caller's thread): the
   markers are followed from the previous frames with :class:`MarkerTracker` (a few
   milliseconds), for the overlay and for deciding whether the frame shows a view the
   collection lacks. If it does, the view is held in the collection
   (:meth:`ViewCollector.reserve`) and the frame queued for precise detection.
2. **In the background** (one thread): precise detection of the queued frames, oldest
   first; their detections settle the held views (:meth:`ViewCollector.settle`: only
   precisely detected markers ever reach a solve) and re-seed the tracker. When nothing
   is queued, the newest frame is detected now and then as well (at most every
   ``refresh_s``): that finds markers the tracker has lost or never had, and its
   detections are offered to the collection too.

The queue is bounded (frames and bytes); a view that finds it full is not held, and a
later frame of the same view gets another chance.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.background import BackgroundTier
from artcal_ros.core.live.coverage import ViewCollector
from artcal_ros.core.live.tracking import MarkerTracker

__all__ = ["LiveConfig", "LiveCounts", "LiveDetection", "LiveFrame"]


@dataclass(frozen=True)
class LiveConfig:
    """Bounds of the background tier.

    Attributes:
        max_queued: frames waiting for precise detection at most.
        max_queued_bytes: their total size at most, bytes.
        refresh_s: with nothing queued, the newest frame is detected precisely at most
            this often, seconds (0: whenever the background tier is idle).
    """

    max_queued: int = 16
    max_queued_bytes: int = 256 * 2**20
    refresh_s: float = 0.2


@dataclass(frozen=True)
class LiveFrame:
    """What the fast tier made of one frame.

    Attributes:
        index: the frame's number in the stream.
        markers: tracked markers (approximate, NaN sigmas), full-resolution pixels.
        queued: the frame shows a new view and waits for precise detection.
    """

    index: int
    markers: Detections
    queued: bool


@dataclass(frozen=True)
class LiveCounts:
    """Background-tier counts since start.

    Attributes:
        measured: frames detected precisely.
        queued: new views waiting for (or in) precise detection now.
        refused: new views not held because the queue was full.
    """

    measured: int
    queued: int
    refused: int


@dataclass(frozen=True)
class _Job:
    index: int
    image: np.ndarray
    ticket: int | None      # a held view, or None for a refresh
    generation: int         # the reset count when it was queued


class LiveDetection(BackgroundTier[_Job]):
    """Tracked markers for every frame and precise detections in the background.

    Args:
        board: the calibration board.
        detect: precise detection of one image (a :class:`Detector`'s ``detect``).
        collector: where views go.
        config: bounds, see :class:`LiveConfig`.
        on_measured: called on the background thread after each precise detection with
            the image, the detections and whether they added a view.
        on_error: called on the background thread with an exception detection raised (the
            frame is skipped, its held view released).
    """

    def __init__(self, board: Board, detect: Callable[[np.ndarray], Detections],
                 collector: ViewCollector, config: LiveConfig | None = None, *,
                 on_measured: Callable[[np.ndarray, Detections, bool], None] | None = None,
                 on_error: Callable[[BaseException], None] | None = None) -> None:
        super().__init__("measure views")
        self.config = config or LiveConfig()
        self.tracker = MarkerTracker(board)
        self.collector = collector
        self._detect = detect
        self._on_measured = on_measured
        self._on_error = on_error
        self._queue: deque[_Job] = deque()
        self._queued_bytes = 0
        self._latest: _Job | None = None
        self._last_refresh = -np.inf
        self._measured = 0
        self._refused = 0
        self._start()

    # --- fast tier -----------------------------------------------------------------
    def offer(self, image: np.ndarray) -> LiveFrame:
        """Track the markers into a new frame; queue it if it shows a new view.

        Args:
            image: (H, W) uint8/uint16 grey or (H, W, 3) uint8 BGR. It is kept (not
                copied) until the background tier is done with it: do not write to it.
        """
        index, markers = self.tracker.track(image)
        ticket = self.collector.reserve(markers) if len(markers) else None
        queued = False
        with self._cond:
            if ticket is not None:
                cfg = self.config
                if (len(self._queue) < cfg.max_queued
                        and self._queued_bytes + image.nbytes <= cfg.max_queued_bytes):
                    self._queue.append(_Job(index, image, ticket, self._generation))
                    self._queued_bytes += image.nbytes
                    queued = True
                else:
                    self._refused += 1
            self._latest = _Job(index, image, None, self._generation)
            self._cond.notify()
        if ticket is not None and not queued:
            self.collector.release(ticket)
        return LiveFrame(index, markers, queued)

    # --- background tier -----------------------------------------------------------
    def _next_job(self) -> _Job | None:
        # Caller holds the condition. Held views first; else the newest frame, rate-limited.
        if self._queue:
            job = self._queue.popleft()
            self._queued_bytes -= job.image.nbytes
            return job
        wait = self._last_refresh + self.config.refresh_s - time.monotonic()
        if self._latest is not None and wait <= 0:
            job, self._latest = self._latest, None
            self._last_refresh = time.monotonic()
            return job
        return None

    def _job_done(self, job: _Job) -> None:
        self._measured += 1

    def _pending(self) -> int:
        return self.collector.pending

    def _work(self, job: _Job) -> None:
        try:
            dets = self._detect(job.image)
        except Exception as e:
            if job.ticket is not None:
                self.collector.release(job.ticket)
            self._report(self._on_error, e)
            return
        # The generation test and the collection's change are one step against reset():
        # a reset either comes before (this detection is dropped) or clears it after.
        with self._commit:
            if job.generation != self._generation:  # measured across a reset
                if job.ticket is not None:
                    self.collector.release(job.ticket)
                return
            self.tracker.seed(job.index, dets)
            if job.ticket is not None:
                kept = self.collector.settle(job.ticket, dets)
            else:
                kept = self.collector.add(dets)
        if self._on_measured is not None:
            self._on_measured(job.image, dets, kept)

    # --- state ---------------------------------------------------------------------
    @property
    def backlog(self) -> int:
        """Frames waiting for precise detection now: a glance taken without the lock (for
        work that should wait while there are some, as the live solve does)."""
        return len(self._queue)

    def counts(self) -> LiveCounts:
        """Frames measured, waiting and refused so far."""
        pending = self.collector.pending
        with self._cond:
            return LiveCounts(self._measured, pending, self._refused)

    def reset(self) -> None:
        """Drop the queued frames and the tracked markers (the collection is reset apart).

        A precise detection still running when this is called adds nothing afterwards.
        """
        with self._commit, self._cond:
            jobs = list(self._queue)
            self._queue.clear()
            self._queued_bytes = 0
            self._latest = None
            self._generation += 1
        for job in jobs:
            if job.ticket is not None:
                self.collector.release(job.ticket)
        self.tracker.reset()

    def _on_stop(self) -> None:
        self._queue.clear()
        self._queued_bytes = 0

    def stop(self, timeout: float = 1.0) -> bool:
        """End the background thread (a detection in progress finishes) and wait up to
        ``timeout`` s for it; whether it ended. Idempotent: call again to wait longer."""
        return self._stop_thread(timeout)
