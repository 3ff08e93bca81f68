"""Sending frames to a node under test until it shows their effect (never one shot).

Discovery is two-sided and takes seconds on a busy machine: a publisher that already sees
the node's subscription may not be seen by the node yet, and a frame published then is
lost. Every send here repeats until the caller's condition holds.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from typing import Any


class Streamer:
    """Publishes ``frames`` round and round from a thread, one every ``period_s``, until
    stopped.

    Attributes:
        sent: frames published so far.
    """

    def __init__(self, publisher: Any, frames: Sequence[Any], period_s: float) -> None:
        self._publisher = publisher
        self._frames = list(frames)
        self._period_s = period_s
        self._stop = threading.Event()
        self.sent = 0
        self._thread = threading.Thread(target=self._run, name="stream", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self._period_s):
            self._publisher.publish(self._frames[self.sent % len(self._frames)])
            self.sent += 1

    def stop(self) -> None:
        """Stop publishing (waits for the thread)."""
        self._stop.set()
        self._thread.join(5.0)


def publish_until(publisher: Any, msg: Any, seen: Callable[[], Any], timeout: float,
                  what: str, *, every_s: float = 2.0) -> Any:
    """Publish ``msg`` every ``every_s`` seconds until ``seen()`` is truthy; its value.

    Raises:
        AssertionError: naming ``what``, after ``timeout`` seconds.
    """
    deadline = time.monotonic() + timeout
    while True:
        publisher.publish(msg)
        resend = time.monotonic() + every_s
        while time.monotonic() < resend:
            value = seen()
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
            time.sleep(0.05)


def send_until_counted(publisher: Any, msg: Any, count: Callable[[], int], target: int,
                       timeout: float, what: str, *, resend_after_s: float = 10.0) -> None:
    """Publish ``msg`` until ``count()`` (the node's own count of frames received, from its
    diagnostics) reaches ``target``; resend only when it has not after ``resend_after_s``,
    so a frame the node received is never sent twice (exact counts stay exact).

    Raises:
        AssertionError: naming ``what``, after ``timeout`` seconds.
    """
    publish_until(publisher, msg, lambda: count() >= target, timeout, what,
                  every_s=resend_after_s)
