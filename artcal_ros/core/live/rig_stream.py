"""Two tiers for a live rig: every camera's frames tracked, rig frames measured in the background.

As :mod:`~artcal_ros.core.live.stream` does for one camera:

1. **Every frame, at once** (:meth:`RigStream.offer`, the caller's thread, one camera at a
   time): the camera's :class:`~artcal_ros.core.live.tracking.MarkerTracker` follows its
   markers into the frame (for the overlay), and the frame goes to the
   :class:`~artcal_ros.core.live.rig_frames.StampPairer`. A rig frame it completes whose
   tracked markers make a new rig view is held in :class:`~artcal_ros.core.live.rig_views.RigViews`
   and queued for precise detection.
2. **In the background** (one worker thread, owned and joined here): each queued rig frame
   is detected precisely, camera by camera, with that camera's own detector; the
   detections re-seed the trackers and settle the held view. With nothing queued, the
   newest rig frame is detected now and then (at most every ``refresh_s``; the newest
   image of each camera while no frame pairs), which finds markers the trackers lost or
   never had. Calls handed to :meth:`RigStream.submit` (the rig's solve) run on the same
   thread, after the rig frames queued before them, and answer through a ``Future``.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future
from dataclasses import dataclass
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.background import BackgroundTier
from artcal_ros.core.live.rig_frames import RigFrame, StampPairer
from artcal_ros.core.live.rig_views import RigViews
from artcal_ros.core.live.tracking import MarkerTracker

__all__ = ["CameraFrame", "RigStream"]

UNPAIRED_AFTER_S = 1.0  # s without a rig frame before single cameras' images are measured


@dataclass(frozen=True)
class CameraFrame:
    """What the fast tier made of one camera's frame.

    Attributes:
        index: the frame's number in its camera's tracker.
        image: the frame (kept, not copied).
        markers: tracked markers (approximate), full-resolution pixels.
        queued: a rig frame completed by this one was queued as a new rig view.
    """

    index: int
    image: np.ndarray
    markers: Detections
    queued: bool = False


@dataclass
class _Job:
    frames: dict[str, CameraFrame]   # the cameras' frames to measure
    ticket: int | None               # a held rig view, or None (a refresh)
    generation: int
    paired: bool = True              # False: each camera's newest image, not one instant
    call: tuple[Callable[[], Any], Future[Any]] | None = None


class RigStream(BackgroundTier[_Job]):
    """Tracked markers for every camera's frames, rig views measured in the background.

    The worker thread is named :attr:`thread_name`.

    Args:
        board: the calibration board.
        names: the cameras.
        detect: camera -> precise detection of one of its images (its Detector's detect).
        views: where rig views go.
        tolerance_ns: rig frame pairing tolerance, nanoseconds (``sync_tolerance``).
        on_measured: called on the worker thread after each measured rig frame with its
            detections (camera -> Detections) and whether it became a rig view.
        on_error: called on the worker thread with an exception a detection raised.
        refresh_s: the newest frame is measured at most this often when nothing is queued.
        max_queued: rig frames waiting for precise detection at most.
    """

    def __init__(self, board: Board, names: Sequence[str],
                 detect: Mapping[str, Callable[[np.ndarray], Detections]], views: RigViews,
                 tolerance_ns: int, *,
                 on_measured: Callable[[dict[str, Detections], bool], None] | None = None,
                 on_error: Callable[[BaseException], None] | None = None,
                 refresh_s: float = 0.3, max_queued: int = 8) -> None:
        self.thread_name = "measure rig views"
        super().__init__(self.thread_name)
        self.names = tuple(names)
        self.views = views
        self.trackers = {n: MarkerTracker(board) for n in self.names}
        self.pairer: StampPairer[CameraFrame] = StampPairer(self.names, tolerance_ns)
        self._detect = dict(detect)
        self._on_measured = on_measured
        self._on_error = on_error
        self.refresh_s = refresh_s
        self.max_queued = max_queued
        self._queue: deque[_Job] = deque()
        self._latest: dict[str, CameraFrame] | None = None      # newest rig frame
        self._newest: dict[str, CameraFrame] = {}               # newest frame per camera
        self._last_refresh = -np.inf
        self._last_paired = -np.inf
        self._measured = {n: 0 for n in self.names}
        self._refused = 0
        self._start()

    # --- fast tier -------------------------------------------------------------------
    def offer(self, name: str, image: np.ndarray, stamp_ns: int) -> CameraFrame:
        """Track the markers into camera ``name``'s new frame and pair it by stamp.

        Args:
            name: the camera.
            image: (H, W) uint8/uint16 grey or (H, W, 3) uint8 BGR; kept, not copied.
            stamp_ns: the image's stamp (header), nanoseconds.
        """
        index, markers = self.trackers[name].track(image)
        frame = CameraFrame(index, image, markers)
        self.views.note_size(name, (image.shape[1], image.shape[0]))
        queued = False
        for rig_frame in self.pairer.add(name, stamp_ns, frame):
            queued |= self._consider(rig_frame)
        with self._cond:
            self._newest[name] = frame
            self._cond.notify()
        return CameraFrame(index, image, markers, queued)

    def _consider(self, rig_frame: RigFrame[CameraFrame]) -> bool:
        frames = rig_frame.items
        ticket = self.views.hold({n: f.markers for n, f in frames.items()})
        with self._cond:
            self._last_paired = time.monotonic()
            generation = self._generation
            self._latest = frames
            if ticket is not None:
                if sum(j.ticket is not None for j in self._queue) < self.max_queued:
                    self._queue.append(_Job(frames, ticket, generation))
                    self._cond.notify()
                    return True
                self._refused += 1
            self._cond.notify()
        if ticket is not None:
            self.views.release(ticket)
        return False

    def submit(self, call: Callable[[], Any]) -> Future[Any]:
        """Run ``call`` on the worker thread after the rig frames queued now; its Future."""
        future: Future[Any] = Future()
        with self._cond:
            if self._stopping:
                future.set_exception(RuntimeError("the rig stream is stopped"))
                return future
            self._queue.append(_Job({}, None, self._generation, call=(call, future)))
            self._cond.notify()
        return future

    # --- background tier ---------------------------------------------------------------
    def _next_job(self) -> _Job | None:
        # Caller holds the condition.
        if self._queue:
            return self._queue.popleft()
        if time.monotonic() - self._last_refresh < self.refresh_s:
            return None
        frames, paired = self._latest, True
        if frames is not None:
            self._latest = None
        elif self._newest and time.monotonic() - self._last_paired > UNPAIRED_AFTER_S:
            # no rig frame for a while (a camera silent, stamps apart): the cameras' newest
            # images still seed their trackers, so each overlay shows its markers; taken at
            # different instants, they never make a rig view
            frames, paired, self._newest = dict(self._newest), False, {}
        if frames is None:
            return None
        self._last_refresh = time.monotonic()
        return _Job(frames, None, self._generation, paired)

    def _on_exit(self) -> None:
        for left in self._queue:
            if left.call is not None:
                left.call[1].cancel()

    def _pending(self) -> int:
        return self.views.pending

    def _work(self, job: _Job) -> None:
        if job.call is not None:
            self._call(*job.call)
        else:
            self._measure(job)

    @staticmethod
    def _call(call: Callable[[], Any], future: Future[Any]) -> None:
        if not future.set_running_or_notify_cancel():
            return
        try:
            future.set_result(call())
        except BaseException as e:  # handed to the caller through the future
            future.set_exception(e)

    def _measure(self, job: _Job) -> None:
        dets: dict[str, Detections] = {}
        try:
            for n, frame in job.frames.items():
                dets[n] = self._detect[n](frame.image)
        except Exception as e:
            if job.ticket is not None:
                self.views.release(job.ticket)
            self._report(self._on_error, e)
            return
        with self._commit:  # against reset(): a frame measured across one adds nothing
            if job.generation != self._generation:
                if job.ticket is not None:
                    self.views.release(job.ticket)
                return
            for n, d in dets.items():
                self.trackers[n].seed(job.frames[n].index, d)
                self._measured[n] += 1
            if job.ticket is not None:
                kept = self.views.settle(job.ticket, dets)
            else:
                kept = job.paired and self.views.add(dets)
        if self._on_measured is not None:
            self._on_measured(dets, kept)

    # --- state -------------------------------------------------------------------------
    def measured(self) -> dict[str, int]:
        """camera -> its frames detected precisely so far."""
        with self._commit:
            return dict(self._measured)

    @property
    def refused(self) -> int:
        """New rig views not held because the queue was full."""
        with self._cond:
            return self._refused

    @property
    def backlog(self) -> int:
        """Work for the worker now: rig views waiting for or in precise detection, and
        queued calls (a solve, a report). For work that should wait while there is some
        (the cameras' live solves); it takes only the views' lock, never the worker's."""
        return max(len(self._queue), self.views.pending)

    def queued(self) -> int:
        """Rig frames waiting for (or in) precise detection."""
        return self.views.pending

    def reset(self) -> None:
        """Drop the queued rig frames, the frames waiting for a partner and the tracked
        markers (the views are reset apart). A detection running now adds nothing."""
        with self._commit, self._cond:
            jobs = [j for j in self._queue if j.call is None]
            self._queue = deque(j for j in self._queue if j.call is not None)
            self._latest = None
            self._newest = {}
            self._generation += 1
        for job in jobs:
            if job.ticket is not None:
                self.views.release(job.ticket)
        self.pairer.reset()
        for tracker in self.trackers.values():
            tracker.reset()

    def stop(self, timeout: float = 1.0) -> bool:
        """End the worker thread and join it (a detection or call in progress finishes
        first, up to ``timeout`` seconds; calls still queued are cancelled); whether it is
        still running."""
        return not self._stop_thread(timeout)
