"""The calibrator node for a rig (``cameras: [a, b, ...]``): views from every camera, one solve.

Interface (names relative, remappable), for each camera ``a`` of ``cameras``:
  subscribes  a/image              (sensor_msgs/Image; a/image/compressed with
                                    image_transport: compressed; reliability as image_qos)
  publishes   ~/a/overlay          (sensor_msgs/Image bgr8: its tracked markers, coverage)
              a/camera_info        (sensor_msgs/CameraInfo; reliable, transient local, depth 1;
                                    a pair with its stereo rectification R and P)
              /diagnostics         (a status per camera and one for the rig, ~1 Hz)
              /tf_static           (where tf2_msgs is installed: each camera in the first's)
  services    ~/calibrate, ~/reset (std_srvs/Trigger)
  calls       a/set_camera_info    (sensor_msgs/SetCameraInfo) when ``commit`` is true
  writes      <dir>/a.yaml ... and <dir>/camchain.yaml, <dir> the directory of output_file

Images of different cameras stamped within ``sync_tolerance`` form a rig frame
(:mod:`~artcal_ros.core.live.rig_frames`); a rig frame in which two or more cameras measure the
board is a rig view. Each image callback (one callback group per camera) tracks its camera's
markers and draws its overlay; ``RigStream``'s one worker thread measures new rig views
precisely and runs ``calibrate_rig``, which ``~/calibrate`` waits for. Every new rig view is
handed to ``RigStatus``: one live solve per camera (threads "live solve", waiting while rig
frames wait for precise detection), whose projection uncertainty makes the rig ready and
whose next pose each overlay draws. With ``calibrate.fix_intrinsics`` the intrinsics in
``<dir>/<camera>.yaml`` are kept.
"""

from __future__ import annotations

import threading
import time
from concurrent.futures import CancelledError
from functools import partial
from pathlib import Path
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from sensor_msgs.srv import SetCameraInfo
from std_srvs.srv import Trigger

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.rig_files import rig_solve_kwargs, write_rig_files
from artcal_ros.core.calibrate.rig_result import RigResult
from artcal_ros.core.calibrate.solve_run import report_said
from artcal_ros.core.camera_info import CameraInfoData, read_camera_info_yaml
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError, ImageFormatError, ParameterError
from artcal_ros.core.images import image_to_numpy
from artcal_ros.core.images.broken_frames import broken_cause
from artcal_ros.core.images.compressed import compressed_to_numpy
from artcal_ros.core.live.overlay import render_overlay
from artcal_ros.core.live.readiness import calibrate_readiness
from artcal_ros.core.live.rig_status import RigStatus
from artcal_ros.core.live.rig_stream import RigStream
from artcal_ros.core.live.rig_views import RigSnapshot, RigViews, RigViewsConfig
from artcal_ros.core.params import ParamValue, output_path, report_path
from artcal_ros.ros import msgs
from artcal_ros.ros.calibrator_common import (
    LATCHED_QOS,
    OVERLAY_QOS,
    answer_calibrate,
    spin_until_stopped,
)
from artcal_ros.ros.diagnostics import Counters
from artcal_ros.ros.image_subscription import QOS_CHECK_S, ImageSubscription
from artcal_ros.ros.parameters import check_update, declare_parameters
from artcal_ros.ros.rig_outputs import (
    call_set_camera_info,
    rig_diagnostics,
    tf_available,
    tf_static_message,
)
from artcal_ros.ros.signals import StopSignals

SOLVE_TIMEOUT_S = 600.0


def rig_requested() -> bool:
    """Whether the calibrator's ``cameras`` parameter names two or more cameras (a rig).

    Read as the calibrator will see it (name, remaps, parameter files, ``-p``) on a short-lived
    node of its name; other values are the single node's to refuse, naming the parameter.
    """
    probe = Node("calibrator", start_parameter_services=False, enable_rosout=False)
    try:
        value: Any = probe.declare_parameter("cameras", [], ParameterDescriptor(
            dynamic_typing=True)).value
    finally:
        probe.destroy_node()
    return isinstance(value, list | tuple) and len(value) >= 2


class RigCalibratorNode(Node):
    """Collects rig views from each ``<camera>/image``, solves the rig on ``~/calibrate``.

    Raises:
        ParameterError: a parameter is bad, or a camera's intrinsics to keep are missing.
    """

    def __init__(self, *, node_name: str = "calibrator", transport: str = "",
                 context: Context | None = None) -> None:
        super().__init__(node_name, context=context)
        self.transport = transport or "as the process's Fast DDS setup"
        self.params: dict[str, ParamValue] = declare_parameters(self)
        names = tuple(str(n) for n in self.params["cameras"])  # type: ignore[union-attr]
        if len(names) < 2:
            raise ParameterError("parameter 'cameras': a rig needs two or more camera names")
        self.names = names
        self.board = Board.from_params(self.params)
        self.output_dir = output_path(self.params).parent
        self.fixed = self._fixed_intrinsics()
        from artcal_ros.core.detect import Detector, DetectorConfig  # after the checks

        config = DetectorConfig.from_params(self.params)
        self.detectors = {n: Detector(self.board, config) for n in names}
        self.views = RigViews(self.board, names, self._views_config(self.params))
        self._stopping = threading.Event()
        # The live solves wait while rig frames wait for precise detection: views come first.
        self.status = RigStatus(self.board, names, self.params,
                                on_error=self._on_live_solve_error,
                                defer_while=lambda: self.stream.backlog > 0)
        self.stream = RigStream(
            self.board, names, {n: d.detect for n, d in self.detectors.items()}, self.views,
            round(float(self.params["sync_tolerance"]) * 1e9), on_error=self._on_worker_error,
            on_measured=self._on_measured)
        self.counters = {n: Counters() for n in names}
        self.frame_ids = dict.fromkeys(names, "")
        self.last_summary = ""
        self._solving = threading.Lock()
        self._output_lock = threading.Lock()   # nothing is published after stop()
        self._closed = False

        services = ReentrantCallbackGroup()
        timers = MutuallyExclusiveCallbackGroup()
        compressed = self.params["image_transport"] == "compressed"
        self.overlay_pubs = {n: self.create_publisher(Image, f"~/{n}/overlay", OVERLAY_QOS)
                             for n in names}
        self.info_pubs = {n: self.create_publisher(CameraInfo, f"{n}/camera_info", LATCHED_QOS)
                          for n in names}
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.tf_pub: Any = None
        if tf_available():
            from tf2_msgs.msg import TFMessage

            self.tf_pub = self.create_publisher(TFMessage, "/tf_static", LATCHED_QOS)
        self.images = {n: ImageSubscription(
            self, CompressedImage if compressed else Image,
            self.resolve_topic_name(f"{n}/image") + ("/compressed" if compressed else ""),
            partial(self._on_image, n), mode=str(self.params["image_qos"]),
            callback_group=MutuallyExclusiveCallbackGroup(),
            on_change=partial(self._on_qos_change, n),
            on_incompatible=self._on_qos_incompatible) for n in names}
        self.create_service(Trigger, "~/calibrate", self._on_calibrate, callback_group=services)
        self.create_service(Trigger, "~/reset", self._on_reset, callback_group=services)
        self.set_info_clients: dict[str, Any] = {
            n: self.create_client(SetCameraInfo, f"{n}/set_camera_info",
                                  callback_group=services) for n in names}
        self.create_timer(1.0, self._publish_diagnostics, callback_group=timers)
        self.create_timer(QOS_CHECK_S, self._choose_image_qos, callback_group=timers)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        topics = ", ".join(s.topic for s in self.images.values())
        self.get_logger().info(
            f"calibrating the rig {', '.join(names)} from {topics} (rig frames: stamps within "
            f"{self.params['sync_tolerance']} s); board {self.board.describe()}; call "
            f"~/calibrate after {self.params['min_views']} rig views; writes "
            f"{self.output_dir}/<camera>.yaml and camchain.yaml; DDS transport: "
            f"{self.transport}")

    @staticmethod
    def _views_config(params: dict[str, ParamValue]) -> RigViewsConfig:
        return RigViewsConfig(min_views=int(params["min_views"]),  # type: ignore[arg-type]
                              max_views=int(params["max_views"]),  # type: ignore[arg-type]
                              points=str(params["points"]))

    def _fixed_intrinsics(self) -> dict[str, CameraInfoData]:
        if not self.params["calibrate.fix_intrinsics"]:
            return {}
        fixed = {}
        for n in self.names:
            path = self.output_dir / f"{n}.yaml"
            if not path.is_file():
                raise ParameterError(
                    f"parameter 'calibrate.fix_intrinsics': camera {n}'s intrinsics are read "
                    f"from {path}, which does not exist (calibrate {n} alone first, or set "
                    "output_file's directory to where the cameras' YAMLs are)")
            try:
                fixed[n] = read_camera_info_yaml(path)
                fixed[n].camera  # noqa: B018 - checks the distortion model is one we solve
            except ArtcalError as e:
                raise ParameterError(f"parameter 'calibrate.fix_intrinsics': {e}") from None
        return fixed

    def _on_image(self, name: str, msg: Image | CompressedImage) -> None:
        # The camera's own callback group: one frame of a camera at a time, cameras at once.
        counters = self.counters[name]
        counters.frame_seen()
        if self._stopping.is_set():
            return
        try:
            image = compressed_to_numpy(msg) if isinstance(msg, CompressedImage) \
                else image_to_numpy(msg)
        except ImageFormatError as e:
            if counters.frame_broken(broken_cause(e)):
                self.get_logger().warning(f"{name}: skipping broken frames: {e} (logged once "
                                          "per cause)")
            return
        self.frame_ids[name] = msg.header.frame_id or self.frame_ids[name] or name
        stamp_ns = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        frame = self.stream.offer(name, image, stamp_ns)
        counters.frame_processed(len(frame.markers))
        pub = self.overlay_pubs[name]
        if self._stopping.is_set() or pub.get_subscription_count() == 0:
            return
        snap = self.views.snapshot()
        readiness = self.status.readiness(snap).for_camera(snap.readiness[name])
        picture = render_overlay(image, frame.markers, snap.counts[name], readiness,
                                 kept=frame.queued,
                                 max_width=int(self.params["overlay.max_width"]))
        self.status.draw(name, picture, image.shape[1], frame.markers)
        overlay = msgs.bgr8_image(picture, msgs.header(msg.header.stamp, self.frame_ids[name]))
        with self._output_lock:
            if not self._closed:
                pub.publish(overlay)

    def _choose_image_qos(self) -> None:
        for sub in self.images.values():
            sub.refresh()

    def _on_qos_change(self, name: str, choice: Any) -> None:  # logged as the single node
        self.get_logger().info(f"{name} image qos: {choice.text()}")

    def _on_qos_incompatible(self, text: str) -> None:
        self.get_logger().warning(text, throttle_duration_sec=10.0)

    def _on_measured(self, dets: dict[str, Detections], kept: bool) -> None:
        # The worker thread: a new rig view goes to the cameras' live solves (returns at once).
        if kept and not self._stopping.is_set():
            self.status.offer(self.views.snapshot())

    def _on_live_solve_error(self, name: str, error: BaseException) -> None:
        if not self._stopping.is_set():
            self.get_logger().info(f"{name}: live solve: {error}", throttle_duration_sec=10.0)

    def _on_worker_error(self, error: BaseException) -> None:
        for c in self.counters.values():
            c.frame_failed()
        if not self._stopping.is_set():
            self.get_logger().error(f"detection failed on a rig frame: {error!r}",
                                    throttle_duration_sec=5.0)

    def _publish_diagnostics(self) -> None:
        snap = self.views.snapshot()
        readiness = self.status.readiness(snap)
        live, uncertainty = self.status.diagnostics(snap, readiness)
        measured = self.stream.measured()
        unpaired = self.stream.pairer.unpaired()
        extra = {n: {**live[n], "frames measured": measured[n], "frames unpaired": unpaired[n],
                     "image qos": self.images[n].choice.text(),
                     "frames missed (publisher sequence)": self.images[n].gaps.missed
                     if self.images[n].gaps.known else "unknown",
                     "tone curve": self.detectors[n].tone.text()} for n in self.names}
        rig = {**uncertainty, "rig frames paired": self.stream.pairer.paired,
               "rig frames queued": self.stream.queued(),
               "rig views refused (queue full)": self.stream.refused,
               "dds transport": self.transport}
        with self._output_lock:
            if self._closed:
                return
            self.diag_pub.publish(rig_diagnostics(
                self.get_name(), {n: c.report() for n, c in self.counters.items()}, snap,
                readiness, self.last_summary, self.get_clock().now().to_msg(), camera_extra=extra,
                rig_extra=rig))

    # --- services ---------------------------------------------------------------------
    def _on_calibrate(self, request: Trigger.Request, response: Trigger.Response
                      ) -> Trigger.Response:
        return answer_calibrate(self, self._solving, self._stopping, self._calibrate, response)

    def _calibrate(self) -> tuple[bool, str]:
        waited = self.stream.wait_idle(timeout=10.0, stopping=self._stopping)
        snap = self.views.snapshot()
        if not snap.enough:
            return False, ("not enough to calibrate the rig: "
                           f"{self.status.readiness(snap).summary()}")
        future = self.stream.submit(partial(self._solve, snap))
        deadline = time.monotonic() + SOLVE_TIMEOUT_S
        while not future.done():
            if self._stopping.is_set() or time.monotonic() > deadline:
                future.cancel()
                return False, "the rig solve did not finish (the node is stopping)"
            time.sleep(0.05)
        try:
            rig: RigResult = future.result()
        except ArtcalError as e:
            return False, str(e)
        except CancelledError:
            return False, "the rig solve was cancelled (the node is stopping)"
        message = self._publish(rig) + f"\nreport: {self._queue_report(rig, snap)}"
        # How far from ready, by each camera's projection uncertainty in this solve.
        bound = float(self.params["readiness.max_uncertainty"])
        message += "".join(
            f"\n{n}: " + calibrate_readiness(
                rig.cameras[n].projection_uncertainty_px, len(snap.views), snap.min_views, bound)
            for n in self.names)
        if not waited:
            message += f" ({self.views.pending} rig views still in detection were left out)"
        self.last_summary = message.splitlines()[0]
        if self.params["commit"]:
            return self._commit(rig, message)
        return True, message

    def _solve(self, snap: RigSnapshot) -> RigResult:
        from artcal_ros.core.calibrate.rig import calibrate_rig

        for n, info in self.fixed.items():
            if tuple(info.image_size) != snap.image_sizes[n]:
                raise ParameterError(
                    f"calibrate.fix_intrinsics: {n}'s YAML is for {info.image_size[0]}x"
                    f"{info.image_size[1]} images, its stream's are {snap.image_sizes[n][0]}x"
                    f"{snap.image_sizes[n][1]}")
        self.get_logger().info(f"solving the rig from {len(snap.views)} rig views")
        return calibrate_rig(snap.detections(), self.board, image_sizes=snap.image_sizes,
                             max_frames=int(self.params["max_views"]),  # type: ignore[arg-type]
                             **rig_solve_kwargs(self.params, self.names, self.fixed))

    def _publish(self, rig: RigResult) -> str:
        """camera_info of every camera, /tf_static, the files; the answer's text."""
        stamp = self.get_clock().now().to_msg()
        frame_ids = {n: self.frame_ids[n] or n for n in self.names}
        self.infos = {n: msgs.camera_info(rig.camera_info(n), msgs.header(stamp, frame_ids[n]))
                      for n in self.names}
        with self._output_lock:
            if not self._closed:
                for n in self.names:
                    self.info_pubs[n].publish(self.infos[n])
                tf = tf_static_message(rig, frame_ids, stamp) if self.tf_pub else None
                if tf is not None:
                    self.tf_pub.publish(tf)
        topics = {n: s.topic for n, s in self.images.items()}
        try:
            written, warnings = write_rig_files(self.output_dir, rig, topics)
            where = f"wrote {', '.join(str(p) for p in written)}"
        except ArtcalError as e:
            warnings, where = [], f"NOT written: {e}"
        for w in warnings:
            self.get_logger().warning(w)
        return "\n".join([*rig.summary().splitlines()[:len(rig.names)], where])

    def _queue_report(self, rig: RigResult, snap: RigSnapshot) -> Path:
        """The rig's report into report_dir on the rig stream's worker, after the answer;
        logged when written, or why not. Returns the directory."""
        from artcal_ros.core.calibrate.rig_report import write_rig_report

        directory, log = report_path(self.params), self.get_logger()

        self.stream.submit(partial(
            write_rig_report, directory, rig, snap.detections(), self.board,
            str(self.params["points"]), summary={"success": True, **rig.to_summary_dict()}),
        ).add_done_callback(report_said(
            directory, lambda ok, text: log.info(text) if ok else log.warning(text),
            stopped=(CancelledError, RuntimeError)))  # RuntimeError: the stream stopped
        return directory

    def _commit(self, rig: RigResult, message: str) -> tuple[bool, str]:
        results = []
        for n in self.names:
            client = self.set_info_clients[n]
            ok, text = call_set_camera_info(client, self.infos[n], self._stopping)
            results.append((ok, f"{n}: {text}"))
        if all(r[0] for r in results):
            return True, f"{message}\ncommitted to " + ", ".join(
                self.resolve_service_name(c.srv_name) for c in self.set_info_clients.values())
        return False, f"{message}\nNOT all committed: " + "; ".join(r[1] for r in results)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        self.stream.reset()
        n = self.views.reset()
        self.status.reset()
        response.success, response.message = True, f"cleared {n} rig views"
        self.get_logger().info(f"~/reset: {response.message}")
        return response

    def _on_set_parameters(self, changes: list[Parameter]) -> Any:
        values, result = check_update(self.params, changes)
        if values is not None:
            self.params = values
            self.views.config = self._views_config(values)
            if self.status.reconfigure(values):
                self.status.offer(self.views.snapshot())
        return result

    def stop(self, timeout: float = 1.0) -> list[str]:
        """Publish nothing more and stop the worker thread and the cameras' live solves,
        joined for up to ``timeout`` seconds in all (a detection or solve in progress
        finishes first). Call it again to wait longer. Returns the names of the node's
        threads still running."""
        self._stopping.set()
        with self._output_lock:
            self._closed = True
        deadline = time.monotonic() + timeout
        left = [self.stream.thread_name] if self.stream.stop(timeout=timeout) else []
        return left + self.status.stop(max(0.0, deadline - time.monotonic()))


def rig_main(transport: str, stop: StopSignals) -> int:
    """Run the rig node until a stop signal (the calibrator's ``main`` with ``cameras``,
    after ``rclpy.init``); the exit status.

    Raises:
        ParameterError: a parameter is bad (the caller refuses to start).
    """
    node = RigCalibratorNode(transport=transport)
    # a thread per camera's images, one for the services, one for the timers
    return spin_until_stopped(node, node.stop, len(node.names) + 2, stop)

