"""The rig calibrator's messages: its /diagnostics, the extrinsics on /tf_static, and the
result sent to a camera driver's set_camera_info.

Diagnostics: one status per camera (``<node>: <camera>``: frames seen, processed, broken,
measured, markers in the last frame, views, coverage, its live solve's ``projection
uncertainty`` and ``next pose``) and one for the rig (``<node>: rig``: ``rig views``, shared
views per pair, the cameras that share too few views with the others, each camera's
``<camera>: projection uncertainty``, ``ready`` and what is missing in words).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping
from typing import Any

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from sensor_msgs.msg import CameraInfo
from sensor_msgs.srv import SetCameraInfo
from std_msgs.msg import Header

from artcal_ros.core.calibrate.rig_files import frame_transforms
from artcal_ros.core.calibrate.rig_result import RigResult
from artcal_ros.core.live.rig_status import RigReadiness
from artcal_ros.core.live.rig_views import RigSnapshot
from artcal_ros.ros.diagnostics import CountsReport


def _status(name: str, hardware_id: str, level: bytes, message: str,
            values: Mapping[str, object]) -> DiagnosticStatus:
    return DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id,
                            values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])


def rig_diagnostics(node_name: str, counts: Mapping[str, CountsReport],
                    snap: RigSnapshot, readiness: RigReadiness, last_solve: str,
                    stamp: Time, *,
                    camera_extra: Mapping[str, Mapping[str, object]],
                    rig_extra: Mapping[str, object]) -> DiagnosticArray:
    """The rig node's DiagnosticArray: a status per camera, then the rig's.

    A camera's status is WARN while its broken frames or detection failures keep coming
    (since the previous report); the rig's while a camera is not connected.

    Args:
        counts: camera -> its counts (:meth:`~artcal_ros.ros.diagnostics.Counters.report`).
        snap: the rig collection now; readiness: its readiness judged by the live solves.
        last_solve: the last ``~/calibrate`` answer.
        camera_extra: camera -> more key/values after the standard ones.
        rig_extra: more key/values of the rig's status.
    """
    statuses = []
    for n in snap.names:
        c = counts[n]
        ready = snap.readiness[n]
        problems = []
        if c.new_broken:
            problems.append(f"{c.new_broken} broken frames in the last second "
                            f"({c.broken_causes})")
        if c.new_failed:
            problems.append(f"detection failed on {c.new_failed} frames in the last second")
        values = {"frames seen": c.seen, "frames processed": c.processed,
                  "frames broken": c.broken, "broken causes": c.broken_causes,
                  "frames failed": c.failed, "markers in last frame": c.markers_last,
                  "views": ready.views, "coverage": f"{ready.coverage:.3f}",
                  "coverage needed": f"{ready.coverage_needed:.3f}",
                  "tilted views": f"{ready.tilted_lr} left/right, {ready.tilted_ud} up/down",
                  **camera_extra.get(n, {})}
        message = "; ".join([*problems, f"{ready.views} views, coverage {ready.coverage:.0%}"])
        statuses.append(_status(f"{node_name}: {n}", n,
                                DiagnosticStatus.WARN if problems else DiagnosticStatus.OK,
                                message, values))
    values = {"rig views": len(snap.views), "views needed": snap.min_views,
              **{f"shared views {a}-{b}": k for (a, b), k in snap.shared.items()},
              "cameras not connected": ", ".join(snap.not_connected),
              "connectivity": snap.problem or "every camera connected",
              "ready": str(readiness.ready).lower(),
              "missing": "; ".join(readiness.missing) or "nothing",
              "projection uncertainty needed": f"{readiness.max_uncertainty_px:.3f}",
              "last calibration": last_solve,
              **rig_extra}
    statuses.append(_status(f"{node_name}: rig", ",".join(snap.names),
                            DiagnosticStatus.WARN if snap.problem else DiagnosticStatus.OK,
                            readiness.summary(), values))
    return DiagnosticArray(header=Header(stamp=stamp), status=statuses)


def tf_static_message(rig: RigResult, frame_ids: Mapping[str, str], stamp: Time) -> Any:
    """A tf2_msgs/TFMessage of :func:`~artcal_ros.core.calibrate.rig_files.frame_transforms`
    (each camera's frame in the reference camera's), or None when tf2_msgs is not installed
    or two cameras share a frame id."""
    try:
        from geometry_msgs.msg import Quaternion, Transform, TransformStamped, Vector3
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    transforms = [TransformStamped(
        header=Header(stamp=stamp, frame_id=parent), child_frame_id=child,
        transform=Transform(translation=Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                            rotation=Quaternion(x=q[0], y=q[1], z=q[2], w=q[3])))
        for parent, child, t, q in frame_transforms(rig, frame_ids)]
    return TFMessage(transforms=transforms) if transforms else None

def tf_available() -> bool:
    """Whether tf2_msgs is installed (a native ROS install; not among the pip wheels)."""
    try:
        import tf2_msgs.msg  # noqa: F401
    except ImportError:
        return False
    return True


def call_set_camera_info(client: Any, info: CameraInfo, stopping: threading.Event
                          ) -> tuple[bool, str]:
    """Send ``info`` to a driver's set_camera_info; (success, what happened)."""
    name = client.srv_name
    if not client.wait_for_service(timeout_sec=2.0):
        return False, f"no {name} service (is the camera driver running?)"
    done = threading.Event()
    future = client.call_async(SetCameraInfo.Request(camera_info=info))
    future.add_done_callback(lambda _: done.set())
    t0 = time.monotonic()
    while not done.wait(0.1):
        if stopping.is_set() or time.monotonic() - t0 > 10.0:
            return False, f"{name} did not answer"
    answer = future.result()
    if answer is None or not answer.success:
        return False, f"{name}: {answer.status_message if answer is not None else 'no answer'}"
    return True, f"committed to {name}"

