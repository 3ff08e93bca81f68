"""The calibrator's counters and their /diagnostics message."""

from __future__ import annotations

from dataclasses import dataclass

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

from artcal_ros.core.coverage import Readiness


@dataclass
class Counters:
    """Frame counts since start-up (``used`` restarts at ~/reset).

    Attributes:
        seen: frames received.
        processed: frames detection ran on.
        used: frames kept as calibration views.
        broken: frames that could not be decoded (bad encoding, step, size, data).
        failed: frames where detection raised an unexpected error.
        markers_last: markers in the last processed frame.
    """

    seen: int = 0
    processed: int = 0
    used: int = 0
    broken: int = 0
    failed: int = 0
    markers_last: int = 0
    broken_reported: int = 0
    failed_reported: int = 0


def diagnostic_array(node_name: str, camera_name: str, counters: Counters, dropped: int,
                     readiness: Readiness, last_solve: str, stamp: Time) -> DiagnosticArray:
    """One DiagnosticStatus named after the node: counts, coverage and readiness.

    Level WARN while broken frames or detection failures keep coming (since the previous
    report), else OK.
    """
    new_broken = counters.broken - counters.broken_reported
    new_failed = counters.failed - counters.failed_reported
    counters.broken_reported = counters.broken
    counters.failed_reported = counters.failed
    problems = []
    if new_broken:
        problems.append(f"{new_broken} broken frames skipped in the last second")
    if new_failed:
        problems.append(f"detection failed on {new_failed} frames in the last second")
    level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
    message = "; ".join([*problems, readiness.summary()])
    values = {
        "frames seen": counters.seen,
        "frames processed": counters.processed,
        "frames used": counters.used,
        "frames dropped (busy)": dropped,
        "frames broken": counters.broken,
        "frames failed": counters.failed,
        "markers in last frame": counters.markers_last,
        "views": readiness.views,
        "views needed": readiness.views_needed,
        "coverage": f"{readiness.coverage:.3f}",
        "coverage needed": f"{readiness.coverage_needed:.3f}",
        "ready": str(readiness.ready).lower(),
        "missing": "; ".join(readiness.missing),
        "last calibration": last_solve,
    }
    status = DiagnosticStatus(
        level=level, name=f"{node_name}: camera calibration", message=message,
        hardware_id=camera_name,
        values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
    return DiagnosticArray(header=Header(stamp=stamp), status=[status])
