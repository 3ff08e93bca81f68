"""The calibrator node: collect views from a live image stream, solve on request.

Interface (names relative, remappable):
  subscribes  image                (sensor_msgs/Image; keep last 5, reliability as image_qos:
                                    by default the publishers', see image_subscription.py)
              image/compressed     (sensor_msgs/CompressedImage, with image_transport: compressed)
  publishes   ~/overlay            (sensor_msgs/Image bgr8: markers, coverage, what is missing)
              ~/coverage           (sensor_msgs/Image bgr8 heat map; transient local)
              /diagnostics         (diagnostic_msgs/DiagnosticArray, ~1 Hz)
              camera_info          (sensor_msgs/CameraInfo; reliable, transient local, depth 1)
  services    ~/calibrate, ~/reset (std_srvs/Trigger)
  calls       set_camera_info      (sensor_msgs/SetCameraInfo) when ``commit`` is true

Threads, each started, owned and joined (:meth:`CalibratorNode.stop`) by one object:
  "track"          the node's keep-latest worker (:class:`~artcal_ros.ros.latest.LatestWorker`):
                   image callbacks only hand it the message; it tracks the markers into the
                   newest frame in a few milliseconds (the fast tier of
                   :class:`~artcal_ros.core.live.stream.LiveDetection`), draws the overlay,
                   and queues the frames that show a new view (frames replaced while it is
                   busy are counted as dropped);
  "measure views"  the LiveDetection's: precise detection of those queued frames (and now
                   and then the newest one); only its detections become views;
  "save session"   the SessionStore's: saves the views every few seconds;
  "live solve"     the LiveStatus's: after every new view, the camera, its projection
                   uncertainty (readiness) and the next pose, latest-wins, never waited for;
  "solve"          the node's :class:`~artcal_ros.core.calibrate.solve_run.SolveWorker`:
                   ``~/calibrate`` waits for the queued views, submits the solve and waits
                   for its future in a reentrant callback, so images keep flowing meanwhile.
State read across them (the frame id, the last summary and board check) is behind one lock.

Unless the user set up Fast DDS themselves, the node's participant gets a 64 MB
shared-memory segment (:mod:`~artcal_ros.ros.transport`), so large frames from a
best-effort camera are not lost in fragments.

The views collected are saved under ``~/.ros/artcal/<camera_name>/`` every few seconds
(``resume: true`` continues them after a stop, crash or kill). SIGINT and SIGTERM, any
number of them, stop the node in order and it exits 0.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from sensor_msgs.srv import SetCameraInfo
from std_srvs.srv import Trigger

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.board_check import BoardCheck, check_board
from artcal_ros.core.calibrate.result import CalibrationResult
from artcal_ros.core.calibrate.solve_run import (
    SolveOutcome,
    SolveWorker,
    queue_report,
    run_solve,
)
from artcal_ros.core.camera_info import as_camera_info
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError, ImageFormatError, ParameterError
from artcal_ros.core.images.broken_frames import broken_cause
from artcal_ros.core.live.board_mismatch import BoardMismatch
from artcal_ros.core.live.coverage import CoverageConfig, ViewCollector
from artcal_ros.core.live.live_status import LiveStatus
from artcal_ros.core.live.overlay import render_heat_map, render_overlay
from artcal_ros.core.live.readiness import calibrate_readiness
from artcal_ros.core.live.stream import LiveDetection
from artcal_ros.core.params import PARAMETERS, ParamValue, report_path
from artcal_ros.ros import msgs
from artcal_ros.ros.calibrator_common import (
    LATCHED_QOS,
    OVERLAY_QOS,
    answer_calibrate,
    spin_until_stopped,
)
from artcal_ros.ros.command_line import CommandHelp, from_specs, handle_arguments, init_ros
from artcal_ros.ros.diagnostics import Counters, diagnostic_array
from artcal_ros.ros.image_subscription import QOS_CHECK_S, ImageSubscription, QosChoice
from artcal_ros.ros.latest import LatestWorker
from artcal_ros.ros.parameters import check_update, declare_parameters
from artcal_ros.ros.rig_calibrator import rig_main, rig_requested
from artcal_ros.ros.saved_session import open_session
from artcal_ros.ros.signals import StopSignals
from artcal_ros.ros.transport import use_large_shared_memory

SWITCH_INTERVAL_S = 0.001


class CalibratorNode(Node):
    """Collects calibration views from ``image`` and solves on ``~/calibrate``.

    Raises:
        ParameterError: a parameter is bad (the message names it).
    """

    def __init__(self, *, node_name: str = "calibrator", transport: str = "",
                 context: Context | None = None) -> None:
        super().__init__(node_name, context=context)
        self.transport = transport or "as the process's Fast DDS setup"
        self.params: dict[str, ParamValue] = declare_parameters(self)
        self.board = Board.from_params(self.params)
        # Detection pulls in OpenCV's ArUco machinery; imported here so a bad parameter
        # is refused before that cost.
        from artcal_ros.core.detect import Detector, DetectorConfig

        self.detector = Detector(self.board, DetectorConfig.from_params(self.params))
        self.board_mismatch = BoardMismatch(self.board)  # names a print that is not this board
        # Coverage is counted on the points the solve will use, as the solve counts it.
        self.collector = ViewCollector(
            self.board, CoverageConfig(min_views=int(self.params["min_views"]),
                                       points=str(self.params["points"])))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.counters = Counters()
        # Written by the track worker and the ~/calibrate callback, read by the timers and
        # the services: only under _status_lock (see the properties below).
        self._status_lock = threading.Lock()
        self._frame_id = "camera"
        self._last_summary = ""
        self._last_board_check = "not measured (no solve yet)"
        self._solving = threading.Lock()
        self._stopping = threading.Event()
        # Held to publish the heat map and the overlay: the latched heat map follows the
        # collection's changes in order, and nothing is published after stop().
        self._output_lock = threading.Lock()
        self._closed = False
        self.session = open_session(self, self.board, self.collector, self.params,
                                    self._stopping)
        try:
            self._wire()
        except BaseException:
            self.session.close()  # the one thread started so far
            raise
        # The threads last, once nothing can refuse the start any more.
        self.live = LiveDetection(self.board, self.detector.detect, self.collector,
                                  on_measured=self._on_measured,
                                  on_error=self._on_worker_error)
        self.solver = SolveWorker(name="solve")
        # The live solve waits while frames wait for precise detection: views come first.
        self.live_status = LiveStatus(self.board, self.params,
                                      on_error=self._on_live_solve_error,
                                      defer_while=lambda: self.live.backlog > 0)
        self.live_status.offer(self.collector.snapshot())  # a resumed session's views
        self.worker: LatestWorker[Any] = LatestWorker(self._process, self._on_worker_error,
                                                      name="track")
        self._publish_coverage()
        self.get_logger().info(
            f"calibrating from '{self.images.topic}' ({self.params['image_transport']}); "
            f"board {self.board.describe()}; call ~/calibrate after "
            f"{self.params['min_views']} views; DDS transport: {self.transport}")

    def _wire(self) -> None:
        """Publishers, the image subscription, services and timers."""
        images = MutuallyExclusiveCallbackGroup()
        services = ReentrantCallbackGroup()
        timers = MutuallyExclusiveCallbackGroup()
        self.overlay_pub = self.create_publisher(Image, "~/overlay", OVERLAY_QOS)
        self.coverage_pub = self.create_publisher(Image, "~/coverage", LATCHED_QOS)
        self.info_pub = self.create_publisher(CameraInfo, "camera_info", LATCHED_QOS)
        self.diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        compressed = self.params["image_transport"] == "compressed"
        self.images = ImageSubscription(
            self, CompressedImage if compressed else Image,
            self.resolve_topic_name("image") + ("/compressed" if compressed else ""),
            self._on_image, mode=str(self.params["image_qos"]), callback_group=images,
            on_change=self._on_qos_change, on_incompatible=self._on_qos_incompatible)
        self.create_service(Trigger, "~/calibrate", self._on_calibrate, callback_group=services)
        self.create_service(Trigger, "~/reset", self._on_reset, callback_group=services)
        self.set_info_client: Any = self.create_client(
            SetCameraInfo, "set_camera_info", callback_group=services)
        self.create_timer(1.0, self._publish_diagnostics, callback_group=timers)
        # Publishers come and go (a driver restarts, a second one starts): the image QoS is
        # chosen again from the graph on this check (the subscription carries no DDS events).
        self.create_timer(QOS_CHECK_S, self._choose_image_qos, callback_group=timers)

    # --- state read across threads ---------------------------------------------------
    @property
    def frame_id(self) -> str:
        """The images' frame id (the newest image's, "camera" before any)."""
        with self._status_lock:
            return self._frame_id

    @property
    def last_summary(self) -> str:
        """The last successful solve's one-line summary ("" before one)."""
        with self._status_lock:
            return self._last_summary

    @property
    def last_board_check(self) -> str:
        """The last solve's board check, in words."""
        with self._status_lock:
            return self._last_board_check

    # --- images -------------------------------------------------------------------
    def _on_image(self, msg: Image | CompressedImage) -> None:
        # Executor thread: hand over and return; the worker does the work.
        self.counters.frame_seen()
        self.worker.offer(msg)

    def _choose_image_qos(self) -> None:
        self.images.refresh()

    def _on_qos_change(self, choice: QosChoice) -> None:
        self.get_logger().info(f"image qos: {choice.text()}")

    def _on_qos_incompatible(self, text: str) -> None:
        self.get_logger().warning(text, throttle_duration_sec=10.0)

    def _process(self, msg: Image | CompressedImage) -> None:
        from artcal_ros.core.images import image_to_numpy
        from artcal_ros.core.images.compressed import compressed_to_numpy

        if self._stopping.is_set():
            return  # shutting down: the node's entities may be gone
        try:
            image = compressed_to_numpy(msg) if isinstance(msg, CompressedImage) \
                else image_to_numpy(msg)
        except ImageFormatError as e:
            self._on_broken_frame(e)
            return
        if msg.header.frame_id:
            with self._status_lock:
                self._frame_id = msg.header.frame_id
        frame = self.live.offer(image)
        self.counters.frame_processed(len(frame.markers))
        if self._stopping.is_set() or self.overlay_pub.get_subscription_count() == 0:
            return
        snap = self.collector.snapshot()  # counts and text of one and the same collection
        picture = render_overlay(image, frame.markers, snap.counts,
                                 self.live_status.readiness(snap.readiness),
                                 kept=frame.queued,
                                 max_width=int(self.params["overlay.max_width"]))
        self.live_status.draw(picture, image.shape[1], frame.markers)
        overlay = msgs.bgr8_image(picture, msgs.header(msg.header.stamp, self.frame_id))
        with self._output_lock:
            if not self._closed:
                self.overlay_pub.publish(overlay)

    def _on_measured(self, image: np.ndarray, dets: Detections, kept: bool) -> None:
        # Background tier: a precise detection; a new view changes the heat map, and a
        # frame without a marker of the board may show another board or dictionary.
        self.board_mismatch.observe(image, len(dets))
        if kept:
            self._publish_coverage()
            self.live_status.offer(self.collector.snapshot())  # returns at once

    def _on_live_solve_error(self, error: BaseException) -> None:
        if not self._stopping.is_set():
            self.get_logger().info(f"live solve: {error}", throttle_duration_sec=10.0)

    def _on_broken_frame(self, error: ImageFormatError) -> None:
        cause = broken_cause(error)
        if self.counters.frame_broken(cause) and not self._stopping.is_set():
            self.get_logger().warning(
                f"skipping broken frames: {error} (logged once per cause; the diagnostics "
                "count them under 'broken causes')")

    def _on_worker_error(self, error: BaseException) -> None:
        self.counters.frame_failed()
        if self._stopping.is_set():
            return  # shutting down: a publisher already destroyed is no detection failure
        self.get_logger().error(f"detection failed on a frame: {error!r}",
                                throttle_duration_sec=5.0)

    def _publish_coverage(self) -> None:
        # Read and publish under one lock: the worker (a new view) and a service (a reset)
        # may publish at once, and an older map must not stay latched after a newer one.
        with self._output_lock:
            if self._closed:
                return
            snap = self.collector.snapshot()
            picture = render_heat_map(snap.counts, snap.image_size)
            stamp = self.get_clock().now().to_msg()
            self.coverage_pub.publish(msgs.bgr8_image(picture,
                                                      msgs.header(stamp, self.frame_id)))

    def _publish_diagnostics(self) -> None:
        # Dropped frames are read before the counts: every frame the worker dropped was
        # counted as seen first, so processed + dropped never exceeds seen in one report.
        dropped = self.worker.dropped
        live = self.live.counts()
        collection = self.collector.readiness()
        self.diag_pub.publish(diagnostic_array(
            self.get_name(), str(self.params["camera_name"]), self.counters.report(),
            dropped, self.live_status.readiness(collection), self.last_summary,
            self.get_clock().now().to_msg(), board_mismatch=self.board_mismatch.finding,
            extra={**self.live_status.diagnostics(collection),
                   "frames measured": live.measured, "frames queued": live.queued,
                   "views refused (queue full)": live.refused,
                   "image qos": self.images.choice.text(),
                   "frames missed (publisher sequence)": self.images.gaps.missed
                   if self.images.gaps.known else "unknown",
                   "dds transport": self.transport,
                   "tone curve": self.detector.tone.text(),
                   "board check": self.last_board_check}))

    # --- services -----------------------------------------------------------------
    def _on_calibrate(self, request: Trigger.Request, response: Trigger.Response
                      ) -> Trigger.Response:
        def calibrate() -> tuple[bool, str]:
            outcome = self._calibrate()
            return outcome.success, outcome.message

        return answer_calibrate(self, self._solving, self._stopping, calibrate, response)

    def _calibrate(self) -> SolveOutcome:
        # The views already seen but still in precise detection belong to this solve.
        waited = self.live.wait_idle(timeout=10.0, stopping=self._stopping)
        # One snapshot: separate reads could pair the views with another collection's size
        # (or none) when a ~/reset or a new image size comes in between.
        snap = self.collector.snapshot()
        readiness, views, size = snap.readiness, snap.views, snap.image_size
        if not readiness.enough_views:
            mismatch = self.board_mismatch.finding
            return SolveOutcome(False, "not enough views to calibrate: "
                                f"{self.live_status.readiness(readiness).summary()}"
                                + (f"; {mismatch}" if mismatch else ""))
        assert size is not None  # there are views
        self.get_logger().info(f"solving from {len(views)} views ({readiness.summary()})")
        # The answer says how far from ready by the solve's own projection uncertainty.
        outcome = run_solve(views, self.board, size, self.params, replace(readiness, missing=()),
                            worker=self.solver, stopping=self._stopping)
        if outcome.result is not None:
            outcome = replace(outcome, message=f"{outcome.message}; " + calibrate_readiness(
                outcome.result.projection_uncertainty_px, len(views),
                int(self.params["min_views"]), float(self.params["readiness.max_uncertainty"])))
        if not waited:
            outcome = replace(outcome, message=f"{outcome.message} ({self.collector.pending} "
                              "views still in detection were left out)")
        if outcome.result is None:
            return outcome
        stamp = self.get_clock().now().to_msg()
        info = msgs.camera_info(as_camera_info(outcome.result),
                                msgs.header(stamp, self.frame_id))
        self.info_pub.publish(info)
        check = check_board([views[i] for i in outcome.result.views_used], self.board,
                            outcome.result.camera)
        outcome = replace(outcome, message=f"{outcome.message}; report: "
                          f"{self._queue_report(outcome.result, views, check)}")
        with self._status_lock:
            self._last_summary = outcome.message
            self._last_board_check = check.text()
        if check.warning:
            self.get_logger().warning(f"board check: {check.warning}")
        if self.params["commit"]:
            committed = self._commit(info, outcome)
            return committed if outcome.success else replace(committed, success=False)
        return outcome

    def _queue_report(self, result: CalibrationResult, views: list[Detections],
                      check: BoardCheck) -> Path:
        log = self.get_logger()
        return queue_report(self.solver, report_path(self.params), result, views, self.board,
                            tone_curve=self.detector.tone.as_dict(),
                            board_check=check.as_dict(), title=str(self.params["camera_name"]),
                            said=lambda ok, text: log.info(text) if ok else log.warning(text))

    def _commit(self, info: CameraInfo, outcome: SolveOutcome) -> SolveOutcome:
        name = self.set_info_client.srv_name
        if not self.set_info_client.wait_for_service(timeout_sec=2.0):
            return SolveOutcome(False, f"{outcome.message}; NOT committed: no {name} service "
                                "(is the camera driver running?)", outcome.result)
        done = threading.Event()
        future = self.set_info_client.call_async(SetCameraInfo.Request(camera_info=info))
        future.add_done_callback(lambda _: done.set())
        t0 = time.monotonic()
        while not done.wait(0.1):
            if self._stopping.is_set() or time.monotonic() - t0 > 10.0:
                return SolveOutcome(False, f"{outcome.message}; NOT committed: {name} did not "
                                    "answer", outcome.result)
        answer = future.result()
        if answer is None or not answer.success:
            why = answer.status_message if answer is not None else "no answer"
            return SolveOutcome(False, f"{outcome.message}; NOT committed: {name}: {why}",
                                outcome.result)
        return SolveOutcome(True, f"{outcome.message}; committed to {name}", outcome.result)

    def _on_reset(self, request: Trigger.Request, response: Trigger.Response
                  ) -> Trigger.Response:
        self.live.reset()
        n = self.collector.reset()
        self.live_status.reset()
        self._publish_coverage()
        response.success = True
        response.message = f"cleared {n} views"
        self.get_logger().info(f"~/reset: {response.message}")
        return response

    def _on_set_parameters(self, changes: list[Parameter]) -> Any:
        values, result = check_update(self.params, changes)
        if values is not None:
            solve_options = [f"{n} = {values[n]}" for n in sorted(values)
                             if n.startswith("calibrate.") and values[n] != self.params[n]]
            # One assignment: a solve starting now reads either the old or the new values.
            self.params = values
            self.collector.config = replace(self.collector.config,
                                            min_views=int(values["min_views"]))
            if self.live_status.reconfigure(values):
                self.live_status.offer(self.collector.snapshot())
            if solve_options:
                self.get_logger().info(f"{', '.join(solve_options)}: the next ~/calibrate "
                                       "solves with it")
        return result

    def stop(self, timeout: float = 1.0) -> list[str]:
        """Stop the node's threads (for shutdown): tracking, precise detection and the
        solve, joined for up to ``timeout`` s in all, then the session's saving (a last
        save of the views as they are now, for resume).

        After this returns nothing more is published (a frame still in detection finishes
        without output), so the node may be destroyed while a thread winds down. Call it
        again to wait longer. Returns the names of the node's threads still running.
        """
        self._stopping.set()
        with self._output_lock:  # waits for a publish in progress
            self._closed = True
        deadline = time.monotonic() + timeout
        self.worker.stop(timeout)
        self.live.stop(max(0.0, deadline - time.monotonic()))
        self.solver.close(max(0.0, deadline - time.monotonic()))
        self.live_status.stop(max(0.0, deadline - time.monotonic()))
        self.session.close()
        return [name for name, alive in (("track", self.worker.alive),
                                         ("measure views", self.live.alive),
                                         ("solve", self.solver.alive),
                                         ("live solve", self.live_status.alive),
                                         ("save session", self.session.alive)) if alive]


HELP = CommandHelp(
    "calibrator",
    "Collects calibration views from the topic 'image' (remap it to the camera's), shows "
    "them on ~/overlay and ~/coverage, and solves on the service ~/calibrate, publishing "
    "camera_info and writing output_file.",
    from_specs(PARAMETERS),
    "calibrator --ros-args --params-file config/calibrator.yaml -r image:=/camera/image_raw")


def main(args: list[str] | None = None) -> int:
    """Entry point of ``ros2 run artcal_ros calibrator`` (console script ``calibrator``);
    ``args``: the whole command line as ``sys.argv`` (default: ``sys.argv``)."""
    status = handle_arguments(sys.argv if args is None else args, HELP)
    if status is not None:
        return status
    # Precise detection runs in the background on one thread of compiled kernels, so the
    # other core stays free for the camera's frames (tracking, overlay, DDS); set
    # ARTCAL_THREADS to give it more.
    os.environ.setdefault("ARTCAL_THREADS", "1")
    transport = use_large_shared_memory()  # before rclpy creates the participant
    # The fast tier makes many short OpenCV calls, each of which gives up the interpreter
    # lock and must take it back; with Python's default 5 ms switch interval each retake
    # can wait that long behind the executor's and precise detection's Python code.
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    stop = StopSignals.install()
    if not init_ros(args, HELP.program, signal_handler_options=SignalHandlerOptions.NO):
        return 2
    try:
        if rig_requested():  # cameras: two or more names
            return rig_main(transport, stop)
        node = CalibratorNode(transport=transport)
    except (ParameterError, ArtcalError) as e:
        rclpy.logging.get_logger("calibrator").fatal(f"refusing to start: {e}")
        rclpy.try_shutdown()
        return 2
    return spin_until_stopped(node, node.stop, 4, stop)


if __name__ == "__main__":
    sys.exit(main())
