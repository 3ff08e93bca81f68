"""The calibrator's counters and their /diagnostics message."""

from __future__ import annotations

import threading
from collections.abc import Mapping
from dataclasses import dataclass

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from artcal_ros.core.images.broken_frames import BrokenTally
from artcal_ros.core.live.coverage import Readiness


@dataclass(frozen=True)
class CountsReport:
    """The frame counts at one instant, and what came since the previous report.

    Attributes:
        seen: frames received.
        processed: frames detection ran on.
        broken: frames that could not be decoded (bad encoding, step, size, data).
        failed: frames where detection raised an unexpected error.
        markers_last: markers in the last processed frame.
        new_broken, new_failed: broken and failed frames since the previous report.
        broken_causes: ``cause: n; ...`` for every kind of broken frame seen so far.
    """

    seen: int
    processed: int
    broken: int
    failed: int
    markers_last: int
    new_broken: int = 0
    new_failed: int = 0
    broken_causes: str = ""


class Counters:
    """Frame counts since start-up, safe to update from several threads at once.

    The executor's image callback, the detection worker and the diagnostics timer run on
    different threads; ``x += 1`` on a shared attribute is a read, an add and a write, and a
    thread switch in between loses a count. Every update and every read here holds one
    lock, so a report is one consistent instant (``processed`` never ahead of ``seen``).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seen = 0
        self._processed = 0
        self._broken = 0
        self._failed = 0
        self._markers_last = 0
        self._broken_causes = BrokenTally()
        self._broken_reported = 0
        self._failed_reported = 0

    def frame_seen(self) -> None:
        """A frame arrived."""
        with self._lock:
            self._seen += 1

    def frame_processed(self, markers: int) -> None:
        """Detection ran on a frame and found ``markers`` markers."""
        with self._lock:
            self._processed += 1
            self._markers_last = markers

    def frame_broken(self, cause: str = "unknown") -> bool:
        """A frame could not be decoded, for ``cause``; True if the first of that cause."""
        with self._lock:
            self._broken += 1
            return self._broken_causes.add(cause)

    def frame_failed(self) -> None:
        """Detection raised an unexpected error on a frame."""
        with self._lock:
            self._failed += 1

    def snapshot(self) -> CountsReport:
        """The counts now (``new_*`` zero; the report marks are left alone)."""
        with self._lock:
            return CountsReport(self._seen, self._processed, self._broken, self._failed,
                                self._markers_last)

    def report(self) -> CountsReport:
        """The counts now and the broken and failed frames since the previous report."""
        with self._lock:
            out = CountsReport(self._seen, self._processed, self._broken, self._failed,
                               self._markers_last, self._broken - self._broken_reported,
                               self._failed - self._failed_reported,
                               self._broken_causes.summary())
            self._broken_reported = self._broken
            self._failed_reported = self._failed
            return out


def diagnostic_array(node_name: str, camera_name: str, counts: CountsReport, dropped: int,
                     readiness: Readiness, last_solve: str, stamp: Time, *,
                     board_mismatch: str = "",
                     extra: Mapping[str, object] | None = None) -> DiagnosticArray:
    """One DiagnosticStatus named after the node: counts, coverage and readiness.

    Level WARN while broken frames or detection failures keep coming (since the previous
    report) or while the markers in view are not the board's, else OK. ``frames used`` is
    the views kept in the collection now (it restarts at ~/reset and when the image size
    changes, as the collection does).

    Args:
        counts: from :meth:`Counters.report`.
        dropped: frames replaced while detection was busy.
        readiness: the collection's state (views, coverage, what is missing).
        board_mismatch: markers in view that are not the board's, in words (WARN).
        extra: more key/values, after the standard ones.
    """
    problems = [board_mismatch] if board_mismatch else []
    if counts.new_broken:
        problems.append(f"{counts.new_broken} broken frames skipped in the last second "
                        f"(so far: {counts.broken_causes})")
    if counts.new_failed:
        problems.append(f"detection failed on {counts.new_failed} frames in the last second")
    level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
    message = "; ".join([*problems, readiness.summary()])
    values = {
        "frames seen": counts.seen,
        "frames processed": counts.processed,
        "frames used": readiness.views,
        "frames dropped (busy)": dropped,
        "frames broken": counts.broken,
        "broken causes": counts.broken_causes,
        "board mismatch": board_mismatch,
        "frames failed": counts.failed,
        "markers in last frame": counts.markers_last,
        "views": readiness.views,
        "views needed": readiness.views_needed,
        "coverage": f"{readiness.coverage:.3f}",
        "coverage needed": f"{readiness.coverage_needed:.3f}",
        "ready": str(readiness.ready).lower(),
        "missing": "; ".join(readiness.missing),
        "last calibration": last_solve,
        **(extra or {}),
    }
    status = DiagnosticStatus(
        level=level, name=f"{node_name}: camera calibration", message=message,
        hardware_id=camera_name,
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    return DiagnosticArray(header=Header(stamp=stamp), status=[status])
