"""A worker thread that always processes the newest item and drops the rest.

Camera frames arrive faster than detection can keep up with on a small
machine. Queueing them would grow without bound and make the overlay lag
further and further behind; instead a one-slot mailbox keeps only the newest
frame, and every frame replaced before the worker took it is counted as
dropped.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from typing import Generic, TypeVar

T = TypeVar("T")


class LatestWorker(Generic[T]):
    """Runs ``handler(item)`` on a daemon thread for the newest offered item only.

    The worker starts its thread and :meth:`stop` joins it.

    Args:
        handler: called with each item taken; exceptions are passed to ``on_error``.
        on_error: called with an exception the handler raised (the worker keeps going).
        name: the thread's name: what the handler does.
    """

    def __init__(self, handler: Callable[[T], None],
                 on_error: Callable[[BaseException], None], *, name: str = "latest") -> None:
        self._handler = handler
        self._on_error = on_error
        self._cond = threading.Condition()
        self._item: T | None = None
        self._has_item = False
        self._stopping = False
        self._busy = False
        self._dropped = 0
        self._taken = 0
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def offer(self, item: T) -> bool:
        """Hand over an item; return False if it replaced one not yet taken (a drop)."""
        with self._cond:
            replaced = self._has_item
            if replaced:
                self._dropped += 1
            self._item = item
            self._has_item = True
            self._cond.notify()
            return not replaced

    @property
    def dropped(self) -> int:
        """Items replaced before the worker took them."""
        with self._cond:
            return self._dropped

    @property
    def taken(self) -> int:
        """Items handed to the handler."""
        with self._cond:
            return self._taken

    @property
    def busy(self) -> bool:
        """Whether the handler is running now (an item taken and not yet finished)."""
        with self._cond:
            return self._busy

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._has_item and not self._stopping:
                    self._cond.wait()
                if self._stopping:
                    return
                item = self._item
                self._item = None
                self._has_item = False
                self._busy = True
                self._taken += 1
            try:
                self._handler(item)  # type: ignore[arg-type]
            except Exception as e:
                # An error handler that fails (say, logging during shutdown) has nowhere
                # left to report to; the worker must live on for the next item regardless.
                with contextlib.suppress(Exception):
                    self._on_error(e)
            finally:
                with self._cond:
                    self._busy = False

    @property
    def alive(self) -> bool:
        """Whether the thread still runs."""
        return self._thread.is_alive()

    def stop(self, timeout: float = 1.0) -> bool:
        """Ask the thread to end (after the item in hand) and wait up to ``timeout``
        seconds; whether it ended. Idempotent: call again to wait longer."""
        with self._cond:
            self._stopping = True
            self._cond.notify()
        self._thread.join(timeout)
        return not self._thread.is_alive()
