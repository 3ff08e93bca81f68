"""Broken frames by cause: what the node counts, reports and logs once per cause, and the
``artcal`` verbs count and name in their summary (one cause table for both).

A camera or a recording that sends one malformed frame usually sends thousands of the
same kind: a log line per frame would drown everything else, and one throttled line
hides that a second kind started. Each distinct cause is logged the first time it is
seen and counted from then on; the diagnostics list every cause with its count.
"""

from __future__ import annotations

import re
import threading

_NUMBER = re.compile(r"\b\d+(?:\.\d+)?\b")  # a number on its own, not mono8's 8
_PARENTHESES = re.compile(r"\s*\([^()]*\)")


def broken_cause(error: BaseException | str) -> str:
    """The kind of fault an error (or a text) describes, the same for every frame with that
    fault: the error's ``cause`` attribute if it has one, else its message's first clause
    with the numbers replaced by ``N`` and asides dropped (``data has 153600 bytes,
    expected ...`` and ``data has 76800 bytes, ...`` are one cause; ``unknown encoding
    'yuv422'`` and ``unknown encoding 'x'`` are two)."""
    cause = getattr(error, "cause", None)
    if isinstance(cause, str) and cause:
        return cause
    text = str(error).split("; ", 1)[0]
    text = _PARENTHESES.sub("", text)
    return _NUMBER.sub("N", text).strip() or (
        type(error).__name__ if isinstance(error, BaseException) else "unknown cause")


class BrokenTally:
    """Counts of broken frames per cause (thread-safe), in the order causes first came."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._counts: dict[str, int] = {}

    def add(self, cause: str) -> bool:
        """Count one frame of ``cause``; True if it is the first of that cause."""
        with self._lock:
            first = cause not in self._counts
            self._counts[cause] = self._counts.get(cause, 0) + 1
            return first

    def counts(self) -> dict[str, int]:
        """``{cause: frames}`` so far."""
        with self._lock:
            return dict(self._counts)

    def total(self) -> int:
        """Broken frames of every cause."""
        with self._lock:
            return sum(self._counts.values())

    def summary(self) -> str:
        """``cause: n; cause: n`` (empty when no frame was broken)."""
        return "; ".join(f"{cause}: {n}" for cause, n in self.counts().items())
