"""A small progress bar for the ``artcal`` command (stderr, no dependencies)."""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator
from typing import Generic, TextIO, TypeVar

T = TypeVar("T")


class Progress(Generic[T]):
    """Draw ``label [#####.....] 12/40 3.1/s`` on a terminal, or a line every 10 % otherwise.

    Use as ``for item in Progress(items, total=n, label="detect"): ...`` or call
    :meth:`update` yourself. Silent when ``enabled`` is False.
    """

    def __init__(self, items: Iterable[T] | None = None, *, total: int | None = None,
                 label: str = "", stream: TextIO | None = None, enabled: bool = True) -> None:
        self._items = items
        self.total = total if total is not None else (
            len(items) if hasattr(items, "__len__") else None)  # type: ignore[arg-type]
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.count = 0
        self._start = time.monotonic()
        self._last_draw = 0.0
        self._last_decile = -1
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())

    def __iter__(self) -> Iterator[T]:
        assert self._items is not None, "Progress was built without items"
        for item in self._items:
            yield item
            self.update()
        self.close()

    def update(self, n: int = 1, note: str = "") -> None:
        """Advance by ``n`` items; ``note`` is shown after the counts."""
        self.count += n
        if not self.enabled:
            return
        now = time.monotonic()
        if self._tty:
            if now - self._last_draw >= 0.1 or self.count == self.total:
                self._last_draw = now
                self.stream.write("\r" + self._line(now, note))
                self.stream.flush()
        elif self.total:
            decile = int(10 * self.count / self.total)
            if decile != self._last_decile:
                self._last_decile = decile
                self.stream.write(self._line(now, note) + "\n")
                self.stream.flush()

    def _line(self, now: float, note: str) -> str:
        rate = self.count / max(now - self._start, 1e-9)
        if self.total:
            width = 30
            filled = int(width * min(self.count, self.total) / self.total)
            bar = "#" * filled + "." * (width - filled)
            text = f"{self.label} [{bar}] {self.count}/{self.total} {rate:.1f}/s"
        else:
            text = f"{self.label} {self.count} {rate:.1f}/s"
        return f"{text} {note}".rstrip()

    def close(self) -> None:
        """Finish the bar's line."""
        if self.enabled and self._tty:
            self.stream.write("\n")
            self.stream.flush()
