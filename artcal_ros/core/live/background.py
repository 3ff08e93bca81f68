"""The background tier of a live stream: one worker thread, owned and joined by its stream.

:class:`~artcal_ros.core.live.stream.LiveDetection` (one camera) and
:class:`~artcal_ros.core.live.rig_stream.RigStream` (a rig) both hand frames to one thread
for precise detection. What they share lives here: the thread's loop (take a job, work it,
repeat until stopped), the generation count that makes a detection started before a reset
add nothing, and the wait for the held views to be settled.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from typing import Generic, TypeVar

__all__ = ["BackgroundTier"]

Job = TypeVar("Job")


class BackgroundTier(Generic[Job]):
    """One worker thread taking jobs until stopped; subclasses say what a job is.

    A subclass sets up its state, then calls :meth:`_start`. Its ``_next_job`` is called
    with ``_cond`` held and returns a job or None (nothing to do now); ``_work`` runs the
    job without it. ``_commit`` is held while detections change the collection, and by a
    reset while it bumps ``_generation``.

    Args:
        thread_name: the worker thread's name.
    """

    def __init__(self, thread_name: str) -> None:
        self._cond = threading.Condition()
        self._commit = threading.Lock()
        self._stopping = False
        self._generation = 0  # counts resets: a detection started before one adds nothing
        self._thread = threading.Thread(target=self._run, name=thread_name, daemon=True)

    def _start(self) -> None:
        self._thread.start()

    # --- what a subclass defines -----------------------------------------------------
    def _next_job(self) -> Job | None:
        raise NotImplementedError

    def _work(self, job: Job) -> None:
        raise NotImplementedError

    def _pending(self) -> int:
        """Held views not yet settled (waited for by :meth:`wait_idle`)."""
        raise NotImplementedError

    def _job_done(self, job: Job) -> None:
        """After each job, with ``_cond`` held."""

    def _on_stop(self) -> None:
        """When told to stop, with ``_cond`` held (what is queued may be dropped)."""

    def _on_exit(self) -> None:
        """When the thread ends, with ``_cond`` held."""

    # --- the thread ------------------------------------------------------------------
    def _run(self) -> None:
        while True:
            with self._cond:
                job = self._next_job()
                while job is None and not self._stopping:
                    self._cond.wait(timeout=0.05)
                    job = self._next_job()
                if self._stopping or job is None:
                    self._on_exit()
                    return
            try:
                self._work(job)
            finally:
                with self._cond:
                    self._job_done(job)
                    self._cond.notify_all()

    @staticmethod
    def _report(on_error: Callable[[BaseException], None] | None, error: BaseException) -> None:
        # The error callback's own failure must not end the worker thread.
        if on_error is not None:
            with contextlib.suppress(Exception):
                on_error(error)

    # --- state -----------------------------------------------------------------------
    def wait_idle(self, timeout: float, stopping: threading.Event | None = None) -> bool:
        """Wait until no held view waits for its precise detection; whether that came."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while self._pending():
                left = deadline - time.monotonic()
                if left <= 0 or self._stopping or (stopping is not None and stopping.is_set()):
                    return False
                self._cond.wait(timeout=min(left, 0.1))
            return True

    @property
    def alive(self) -> bool:
        """Whether the worker thread still runs."""
        return self._thread.is_alive()

    def _stop_thread(self, timeout: float) -> bool:
        """Tell the thread to end (a job in progress finishes) and join it for up to
        ``timeout`` s; whether it ended."""
        with self._cond:
            self._stopping = True
            self._on_stop()
            self._cond.notify_all()
        self._thread.join(timeout)
        return not self._thread.is_alive()
