"""Rig frames from live image streams: each camera's images paired by stamp as they arrive.

The same rule as :func:`~artcal_ros.core.sync.pair_by_stamp` (a bag's pairing; the rule itself
is :func:`~artcal_ros.core.sync.group_end`): images of different cameras within
``tolerance_ns`` of a frame's first stamp form one rig frame, each image in at most one. A
live stream cannot wait for the whole recording, so a frame is given out as soon as it is
final: every camera is in it, or every camera missing from it has already sent an image
stamped after the frame's window (its stamps rise), or the frame is ``max_lag_ns`` older
than the newest image (a camera that stopped sending). A frame of one camera is no rig
frame: its image is counted as unpaired. ::

    pairer = StampPairer(("left", "right"), tolerance_ns=10_000_000)
    pairer.add("left", 1_000_000_000, left_image)          # -> []
    pairer.add("right", 1_003_000_000, right_image)        # -> [RigFrame(...)]
"""

from __future__ import annotations

import bisect
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

from artcal_ros.core.errors import ParameterError
from artcal_ros.core.sync import group_end

T = TypeVar("T")

__all__ = ["RigFrame", "StampPairer"]


@dataclass(frozen=True)
class RigFrame(Generic[T]):
    """Images of different cameras taken together.

    Attributes:
        stamp_ns: the earliest stamp in it, nanoseconds.
        items: camera -> what was added with its image (two or more cameras).
        stamps_ns: camera -> its image's stamp, nanoseconds.
    """

    stamp_ns: int
    items: dict[str, T]
    stamps_ns: dict[str, int]


class StampPairer(Generic[T]):
    """Pairs the images of several cameras into rig frames as they arrive (thread-safe).

    Args:
        names: the cameras.
        tolerance_ns: the largest stamp difference within a rig frame, nanoseconds (>= 0).
        max_lag_ns: a frame waits for its missing cameras at most this long behind the
            newest image, nanoseconds of stamp time.
        max_pending: images held unpaired at most (the oldest go first).
    """

    def __init__(self, names: Sequence[str], tolerance_ns: int, *,
                 max_lag_ns: int = 1_000_000_000, max_pending: int = 64) -> None:
        if tolerance_ns < 0:
            raise ParameterError(f"sync tolerance {tolerance_ns} ns must be >= 0")
        self.names = tuple(names)
        self.tolerance_ns = int(tolerance_ns)
        self.max_lag_ns = int(max_lag_ns)
        self.max_pending = int(max_pending)
        self._lock = threading.Lock()
        self._pending: list[tuple[int, str, int, T]] = []   # (stamp, camera, arrival, item)
        self._last: dict[str, int] = {}
        self._arrivals = 0
        self._paired = 0
        self._unpaired = {n: 0 for n in self.names}

    def add(self, name: str, stamp_ns: int, item: T) -> list[RigFrame[T]]:
        """One camera's image; the rig frames it completes (oldest first, often none).

        A camera whose stamps jump back by more than ``max_lag_ns`` (a recording played
        again, a clock reset) starts the pairing afresh.

        Raises:
            ParameterError: ``name`` is not one of the cameras.
        """
        if name not in self._unpaired:
            raise ParameterError(f"camera {name!r} is not one of {', '.join(self.names)}")
        stamp = int(stamp_ns)
        with self._lock:
            last = self._last.get(name)
            if last is not None and stamp < last - self.max_lag_ns:
                self._drop(len(self._pending))
                self._last.clear()
                last = None
            self._arrivals += 1
            bisect.insort(self._pending, (stamp, name, self._arrivals, item),
                          key=lambda e: (e[0], e[2]))
            self._last[name] = max(stamp, last if last is not None else stamp)
            out = self._final_frames()
            if len(self._pending) > self.max_pending:
                self._drop(len(self._pending) - self.max_pending)
            return out

    def _final_frames(self) -> list[RigFrame[T]]:
        # Caller holds the lock.
        out: list[RigFrame[T]] = []
        newest = max(self._last.values())
        while self._pending:
            j = group_end(self._pending, 0, self.tolerance_ns)
            group = self._pending[:j]
            start = group[0][0]
            missing = set(self.names) - {e[1] for e in group}
            closed = (not missing or newest - start > self.max_lag_ns
                      or all(self._last.get(m, start) > start + self.tolerance_ns
                             for m in missing))
            if not closed:
                break
            del self._pending[:j]
            if len(group) >= 2:
                self._paired += 1
                out.append(RigFrame(start, {e[1]: e[3] for e in group},
                                    {e[1]: e[0] for e in group}))
            else:
                self._unpaired[group[0][1]] += 1
        return out

    def _drop(self, n: int) -> None:
        # Caller holds the lock: the oldest n images leave unpaired.
        for _, name, _, _ in self._pending[:n]:
            self._unpaired[name] += 1
        del self._pending[:n]

    @property
    def paired(self) -> int:
        """Rig frames given out so far."""
        with self._lock:
            return self._paired

    def unpaired(self) -> dict[str, int]:
        """camera -> its images left out of every rig frame so far."""
        with self._lock:
            return dict(self._unpaired)

    def reset(self) -> None:
        """Forget the images waiting for a partner (not counted as unpaired)."""
        with self._lock:
            self._pending.clear()
            self._last.clear()
