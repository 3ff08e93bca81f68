"""The calibrator node under load: the real node over real DDS, fed at a camera's rate.

    python -m bench.node_load                      # the runs of docs/benchmarks.md
    python -m bench.node_load --quick              # one short 640 x 480 run
    python -m bench.node_load --width 1920 --height 1080 --rate 30 --seconds 60 \
        --encoding rgb8 --reliable
    python -m bench.node_load --dds-only ...       # the same stream, no node: DDS alone
    python -m bench.node_load --alone ...          # the same stream, nobody subscribed
    python -m bench.node_load --fastdds-profile artcal_ros/ros/fastdds_large_shm.xml  # all

Without ``--fastdds-profile`` the publisher (the camera driver's stand-in) and this process
use Fast DDS's defaults, and the node its own 64 MB shared-memory segment, as a user's node
does (:mod:`artcal_ros.ros.transport`). Each full run is followed by the same stream with no
subscriber at all, so the publisher's rate with and without the node is compared.

One run: a few views are rendered once with :mod:`artcal_ros.synth` (a hand-held sweep of
:func:`~artcal_ros.synth.smooth_poses`, played back and forth), the node is started as
``python -m artcal_ros.ros.calibrator`` on a private DDS domain, and a publisher in a child
process sends the views on its ``image`` topic at ``--rate`` with fresh header stamps (the
publisher's clock at send time). This process measures, meanwhile:

- frames sent (the child), seen / processed / dropped (busy) / broken (the node's last
  /diagnostics after the stream has drained); sent - seen is lost between the publisher
  and the node's image callback (DDS, or replaced in the subscription's depth-1 queue);
- overlay latency: arrival at a RELIABLE ``~/overlay`` subscriber here minus the frame's
  stamp (the overlay carries it), median and p95, first and last 10 s of the stream; and
  how many overlays a BEST_EFFORT subscriber receives at the same time;
- the node's resident memory (VmRSS from /proc, once a second): after 10 s, at the end;
- the ``~/calibrate`` response time when called after the stream, and its answer;
- for comparison, the detector's time per frame in this process on the same frames
  (before the node starts, nothing else of ours running).

The node is stopped with SIGINT at the end of every run (SIGKILL if it ignores it).
:func:`run_load` is the core, used by the smoke test as well.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.ros.processes import NodeProcess, private_domain_env

# The node's default overlay.max_width (artcal_ros/core/params.py): the overlay's width cap.
OVERLAY_MAX_WIDTH = 960
# (width, height, rate Hz, seconds, encoding, reliable publisher) of the full set in
# docs/benchmarks.md: what colour and 1080p cameras send.
FULL_RUNS = ((640, 480, 30.0, 60.0, "bgr8", True), (1920, 1080, 30.0, 60.0, "rgb8", True),
             (1920, 1080, 30.0, 60.0, "mono8", False), (3840, 2160, 15.0, 30.0, "bgr8", True))
QUICK_RUN = (640, 480, 10.0, 8.0)
WINDOW_S = 10.0  # "first / last 10 s" of the stream, and the memory warm-up time


@dataclass(frozen=True)
class LoadSpec:
    """One run.

    Attributes:
        width, height: frame size, pixels.
        rate_hz: frames per second sent.
        seconds: how long the stream lasts.
        encoding: the frames' ROS encoding (mono8, mono16, bgr8, rgb8).
        views: distinct rendered views, cycled back and forth (16: enough for the node to
            keep the 10 views ``~/calibrate`` needs, if it processes enough frames).
        reliable: publish RELIABLE (else BEST_EFFORT; the node's image_qos auto follows).
        depth: the publisher's history depth (KEEP_LAST; 5 as ROS's sensor-data profile).
        node: run the calibrator (False: DDS alone, this process subscribes to the frames
            with the node's image QoS instead).
        alone: with ``node`` False, nobody subscribes to the frames (the publisher's own
            rate, for comparison).
        baseline: time the detector on the frames in this process first.
        seed: the poses' and photometry's seed.
        node_name: the node's name (its topics are ``/<node_name>/overlay`` ...); the frames
            go to ``/<node_name>_load/image``, so runs on one domain keep apart.
    """

    width: int
    height: int
    rate_hz: float
    seconds: float
    encoding: str = "mono8"
    views: int = 16
    reliable: bool = False
    depth: int = 5
    node: bool = True
    alone: bool = False
    baseline: bool = True
    seed: int = 11
    node_name: str = "calibrator"

    @property
    def image_topic(self) -> str:
        """Where the publisher sends the frames (the node's ``image``, remapped)."""
        return f"/{self.node_name}_load/image"

    @property
    def overlay_topic(self) -> str:
        """The node's ``~/overlay``."""
        return f"/{self.node_name}/overlay"


@dataclass
class LoadResult:
    """What one run measured (times in seconds, memory in kB; None: not measured).

    ``latency`` holds (frame stamp - stream start, overlay arrival - frame stamp) for every
    overlay the reliable subscriber received (with ``node`` False: every frame received).
    ``rss_kb`` holds (time - stream start, VmRSS) samples.
    """

    spec: LoadSpec
    transport: str = "default"  # the Fast DDS profile file's name, or default
    load_before: tuple[float, float, float] = (0.0, 0.0, 0.0)
    load_after: tuple[float, float, float] = (0.0, 0.0, 0.0)
    render_s: float = 0.0
    detect_s: float | None = None  # median in-process detection time per frame
    frame_bytes: int = 0
    sent: int = 0
    stream_s: float = 0.0
    publish_ms: float | None = None  # median time in publish() in the publisher
    late_ticks: int = 0  # send times the publisher missed by more than a frame interval
    diagnostics: dict[str, str] = field(default_factory=dict)
    latency: list[tuple[float, float]] = field(default_factory=list)
    overlays_reliable: int = 0
    overlays_best_effort: int = 0
    overlay_size: tuple[int, int] | None = None  # (width, height) of the overlays received
    overlay_bytes: int = 0
    rss_kb: list[tuple[float, int]] = field(default_factory=list)
    drained: bool = False
    calibrate_s: float | None = None
    calibrate_success: bool | None = None
    calibrate_message: str = ""
    node_exit: int | None = None
    node_killed: bool = False
    error: str = ""

    # --- derived figures ---------------------------------------------------------
    def count(self, key: str) -> int | None:
        """An integer /diagnostics value (``frames seen`` ...), None if not received."""
        value = self.diagnostics.get(key)
        return int(value) if value is not None and value.lstrip("-").isdigit() else None

    def latencies(self, start: float = -1e9, end: float = 1e9) -> list[float]:
        """Latencies of the frames stamped in [start, end) seconds after the stream start."""
        return [lat for t, lat in self.latency if start <= t < end]

    def latency_stats(self) -> tuple[float | None, float | None]:
        """(median, p95) latency over the whole run."""
        lats = self.latencies()
        if not lats:
            return None, None
        return statistics.median(lats), float(np.percentile(lats, 95))

    def latency_first_last(self) -> tuple[float | None, float | None]:
        """Median latency of the frames stamped in the first and in the last 10 s."""
        first = self.latencies(0.0, WINDOW_S)
        last = self.latencies(self.stream_s - WINDOW_S, self.stream_s + 1.0)
        return (statistics.median(first) if first else None,
                statistics.median(last) if last else None)

    def node_frame_s(self) -> float | None:
        """Seconds a frame took in the node: the stream's length over the frames processed.

        Only given when the node was busy throughout (at least as many frames dropped as
        processed: a frame was waiting whenever detection finished), else its worker also
        waited for frames and the quotient says nothing (None).
        """
        processed, dropped = self.count("frames processed"), self.count("frames dropped (busy)")
        if not processed or dropped is None or dropped < processed:
            return None
        return self.stream_s / processed

    def rss_warm_end(self) -> tuple[int | None, int | None]:
        """VmRSS 10 s into the stream and at its end (the last sample before it ended)."""
        warm = next((kb for t, kb in self.rss_kb if t >= WINDOW_S), None)
        during = [kb for t, kb in self.rss_kb if t <= self.stream_s + 0.5]
        return warm, (during[-1] if during else None)

    def rss_peaks(self) -> tuple[int | None, int | None]:
        """Largest VmRSS in 10-20 s and in the last 10 s of the stream.

        A frame in detection holds some 100 MB of temporaries at 1080p, so single samples
        swing with where the detector is; the peaks (resident base plus one frame) are what
        would show a leak.
        """
        early = [kb for t, kb in self.rss_kb if WINDOW_S <= t < 2 * WINDOW_S]
        late = [kb for t, kb in self.rss_kb
                if self.stream_s - WINDOW_S <= t <= self.stream_s + 0.5]
        return (max(early) if early else None), (max(late) if late else None)


# --- frames -------------------------------------------------------------------------
def camera_for(width: int, height: int) -> Any:
    """A synth camera of the given size: the preset of the nearest aspect ratio, scaled."""
    from artcal_ros.synth import Camera

    base = min((Camera.preset(name) for name in ("webcam", "hd")),
               key=lambda c: abs(c.size[0] / c.size[1] - width / height))
    K = np.array(base.K, dtype=np.float64)
    sx, sy = width / base.size[0], height / base.size[1]
    # Square pixels stay square: one focal scale; the principal point follows each axis.
    K[0, 0] *= sx
    K[1, 1] *= sx
    K[0, 2] *= sx
    K[1, 2] *= sy
    return Camera(base.model, K, np.array(base.dist), (width, height))


def render_frames(spec: LoadSpec) -> list[np.ndarray]:
    """``spec.views`` views of a hand-held sweep, rendered once, in ``spec.encoding``."""
    from artcal_ros.core.board import Board
    from artcal_ros.synth import Photometry, render_view, smooth_poses

    board = Board()  # the node's default board (config/calibrator.yaml is the same)
    cam = camera_for(spec.width, spec.height)
    rng = np.random.default_rng(spec.seed)
    # A key view every other frame: neighbours differ enough that the node keeps several.
    poses = smooth_poses(board, cam, spec.views, rng, frames_per_key=2)
    return [render_view(board, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng,
                        encoding=spec.encoding).image for rvec, tvec in poses]


def play_order(n: int) -> list[int]:
    """0, 1, ..., n-1, n-2, ..., 1: back and forth, so the camera never jumps."""
    return list(range(n)) + list(range(n - 2, 0, -1))


def detection_time(frames: Sequence[np.ndarray], encoding: str, repeats: int = 3) -> float:
    """Median time of the node's per-frame work (decode + detect) on ``frames``, here."""
    from artcal_ros.core.board import Board
    from artcal_ros.core.detect import Detector
    from artcal_ros.core.images import image_to_numpy, numpy_to_image

    detector = Detector(Board())
    times = []
    for k in range(repeats):
        msg = numpy_to_image(frames[k % len(frames)], encoding)
        t0 = time.perf_counter()
        detector.detect(image_to_numpy(msg))
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


# --- the publisher (a child process) --------------------------------------------------
def publisher_main(spec_path: Path) -> int:
    """The child: wait for a subscriber, stream the frames, write a JSON result.

    A separate process so that sending 8 MB frames and receiving overlays do not share one
    interpreter lock, and the publisher's timing is its own.
    """
    import rclpy
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    job = json.loads(Path(spec_path).read_text())
    result: dict[str, Any] = {"sent": 0, "error": ""}
    frames = np.load(job["frames"])
    rclpy.init()
    node = rclpy.create_node("load_publisher")
    try:
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=int(job["depth"]),
                         reliability=ReliabilityPolicy.RELIABLE if job["reliable"]
                         else ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)
        pub = node.create_publisher(Image, job["topic"], qos)
        from artcal_ros.core.images import numpy_to_image

        msgs = []
        for frame in frames:
            fields = numpy_to_image(frame, job["encoding"], frame_id="camera")
            fields.pop("header")
            msgs.append(Image(**fields))
        deadline = time.monotonic() + float(job["discovery_timeout"])
        while pub.get_subscription_count() < job["subscribers"]:
            if time.monotonic() > deadline:
                result["error"] = (f"no subscriber matched {job['topic']} within "
                                   f"{job['discovery_timeout']} s")
                return 1
            time.sleep(0.05)
        order = play_order(len(msgs))
        period = 1.0 / float(job["rate_hz"])
        publish_s: list[float] = []
        late = 0
        clock = node.get_clock()
        start = time.monotonic()
        result["start_ns"] = time.time_ns()
        next_t = start
        i = 0
        # Frame i is due at start + i / rate; the stream ends at the first due time past
        # ``seconds``, so a run sends rate x seconds frames unless the machine is too busy.
        while next_t - start < float(job["seconds"]):
            now = time.monotonic()
            if now < next_t:
                time.sleep(next_t - now)
            elif now - next_t > period:
                # Fell behind by more than a frame (a busy machine): a camera does not send
                # the missed frames in a burst afterwards, so neither do we.
                late += 1
                next_t = now
            msg = msgs[order[i % len(order)]]
            msg.header.stamp = clock.now().to_msg()
            t0 = time.perf_counter()
            pub.publish(msg)
            publish_s.append(time.perf_counter() - t0)
            i += 1
            next_t += period
        result["end_ns"] = time.time_ns()
        result["sent"] = i
        result["late_ticks"] = late
        result["publish_ms"] = 1e3 * statistics.median(publish_s) if publish_s else None
        # Fast DDS sends large samples from its own thread: let the last one leave.
        time.sleep(0.5)
        return 0
    except KeyboardInterrupt:
        result["error"] = "interrupted"
        return 130
    finally:
        Path(job["result"]).write_text(json.dumps(result))
        node.destroy_node()
        rclpy.try_shutdown()


# --- this process's side: subscribers, diagnostics, service ---------------------------
class Listener:
    """An rclpy node here, spun on a background thread, recording what the node publishes.

    Callbacks only append small tuples (no message is kept: 4K frames add up fast).
    """

    def __init__(self, spec: LoadSpec) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Image

        self.context = Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node("load_listener", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.lock = threading.Lock()
        self.reliable: list[tuple[int, int, int, int, int]] = []  # recv ns, stamp ns, w, h, B
        self.best_effort = 0
        self.diagnostics: list[tuple[int, dict[str, str]]] = []  # (recv ns, values)
        self.node_name = spec.node_name
        self.subs: list[Any] = []
        if spec.node:
            reliable = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                  reliability=ReliabilityPolicy.RELIABLE)
            best_effort = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                                     reliability=ReliabilityPolicy.BEST_EFFORT)
            self.subs.append(self.node.create_subscription(Image, spec.overlay_topic,
                                                           self._on_overlay, reliable))
            self.subs.append(self.node.create_subscription(Image, spec.overlay_topic,
                                                           self._on_best_effort, best_effort))
            self.subs.append(self.node.create_subscription(DiagnosticArray, "/diagnostics",
                                                           self._on_diagnostics, 10))
        elif not spec.alone:
            # The QoS the node's image_qos auto chooses for this publisher, to see what DDS
            # alone delivers to such a subscription.
            from artcal_ros.ros.image_subscription import image_qos

            self.subs.append(self.node.create_subscription(
                Image, spec.image_topic, self._on_overlay, image_qos(spec.reliable)))
        self._thread = threading.Thread(target=self._spin, name="listener", daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        from rclpy.executors import ExternalShutdownException

        with contextlib.suppress(ExternalShutdownException, RuntimeError):
            while self.context.ok():
                self.executor.spin_once(timeout_sec=0.05)

    def _on_overlay(self, msg: Any) -> None:
        now = time.time_ns()  # first: the arrival as this subscriber's code sees it
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        with self.lock:
            self.reliable.append((now, stamp, msg.width, msg.height, len(msg.data)))

    def _on_best_effort(self, msg: Any) -> None:
        with self.lock:
            self.best_effort += 1

    def _on_diagnostics(self, msg: Any) -> None:
        for status in msg.status:
            if status.name.startswith(f"{self.node_name}:"):
                values = {kv.key: kv.value for kv in status.values}
                with self.lock:
                    self.diagnostics.append((time.time_ns(), values))

    def last_diagnostics(self, after_ns: int = 0) -> dict[str, str] | None:
        """The newest diagnostics values received after ``after_ns`` (None if none)."""
        with self.lock:
            if self.diagnostics and self.diagnostics[-1][0] > after_ns:
                return self.diagnostics[-1][1]
        return None

    def matched(self) -> bool:
        """Whether every subscription here has matched a publisher."""
        return all(s.get_publisher_count() >= 1 for s in self.subs)

    def call_trigger(self, name: str, timeout: float) -> tuple[float, bool, str]:
        """Call a std_srvs/Trigger; (response time s, success, message).

        Raises:
            TimeoutError: the service did not appear or did not answer in time.
        """
        from std_srvs.srv import Trigger

        client: Any = self.node.create_client(Trigger, name)
        try:
            if not client.wait_for_service(timeout_sec=30.0):
                raise TimeoutError(f"service {name} did not appear within 30 s")
            t0 = time.monotonic()
            future = client.call_async(Trigger.Request())
            while not future.done():
                if time.monotonic() - t0 > timeout:
                    raise TimeoutError(f"{name} did not answer within {timeout:g} s")
                time.sleep(0.01)
            elapsed = time.monotonic() - t0
            answer = future.result()
            if answer is None:
                return elapsed, False, "no answer (the call failed)"
            return elapsed, bool(answer.success), str(answer.message)
        finally:
            self.node.destroy_client(client)

    def close(self) -> None:
        import rclpy

        rclpy.try_shutdown(context=self.context)
        self._thread.join(2.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()


def vm_rss_kb(pid: int) -> int | None:
    """The process's resident memory (VmRSS) in kB; None once it has ended."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError):
        return None
    return None


def wait_for(predicate: Callable[[], Any], timeout: float, what: str,
             alive: Callable[[], bool] = lambda: True, period: float = 0.05) -> Any:
    """Poll ``predicate`` until truthy; TimeoutError naming ``what`` (or a process died)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if not alive():
            raise RuntimeError(f"a process ended while waiting for {what}")
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(period)


@contextlib.contextmanager
def _started(proc: NodeProcess, stop_timeout: float) -> Iterator[NodeProcess]:
    """Stop ``proc`` with SIGINT (SIGKILL after ``stop_timeout``) however the block ends."""
    try:
        yield proc
    finally:
        proc.stop(stop_timeout)


def run_load(spec: LoadSpec, work_dir: Path, *, discovery_timeout: float = 60.0,
             drain_timeout: float | None = None,
             log: Callable[[str], None] = lambda s: print(s, flush=True),
             frames: Sequence[np.ndarray] | None = None) -> LoadResult:
    """One run (see the module docstring); the node and the publisher are always stopped.

    Uses the ROS environment of this process as it is (ROS_DOMAIN_ID,
    ROS_AUTOMATIC_DISCOVERY_RANGE and any FASTDDS_DEFAULT_PROFILES_FILE, set before any
    rclpy context exists): the node and the publisher inherit it.

    Args:
        spec: the run.
        work_dir: for the frames, the logs (``calibrator.log``, ``publisher.log``), the
            node's calibration file.
        discovery_timeout: how long the node, publisher and subscribers may take to find
            each other, seconds (discovery takes up to ~3.5 s on an idle machine).
        drain_timeout: how long to wait after the stream for the node's last frame to
            finish (default: 30 s or 4 detections, whichever is longer).
        frames: the views to send, already rendered for ``spec`` (default: render them).
    """
    work_dir = Path(work_dir)
    work_dir.mkdir(parents=True, exist_ok=True)
    profile = os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE", "")
    result = LoadResult(spec=spec, transport=Path(profile).name if profile else "default",
                        load_before=os.getloadavg())
    t0 = time.monotonic()
    given = frames is not None
    frames = list(frames) if frames is not None else render_frames(spec)
    result.render_s = time.monotonic() - t0
    result.frame_bytes = int(frames[0].nbytes)
    np.save(work_dir / "frames.npy", np.stack(frames))
    log(f"  {'the same' if given else 'rendered'} {len(frames)} views {spec.width}x"
        f"{spec.height} {spec.encoding}"
        + ("" if given else f" in {result.render_s:.1f} s")
        + f" ({result.frame_bytes / 1e6:.2f} MB a frame)")
    if spec.baseline:
        result.detect_s = detection_time(frames, spec.encoding)
        log(f"  detection here: {result.detect_s:.2f} s a frame (median of 3)")
    if drain_timeout is None:
        drain_timeout = max(30.0, 4.0 * (result.detect_s or 5.0))

    node: NodeProcess | None = None
    listener: Listener | None = None
    with contextlib.ExitStack() as stack:
        if spec.node:
            node = NodeProcess.python_module(
                "artcal_ros.ros.calibrator",
                ["--ros-args", "-r", f"__node:={spec.node_name}",
                 "-r", f"image:={spec.image_topic}",
                 "-p", f"output_file:={work_dir / 'camera.yaml'}"],
                work_dir / "calibrator.log", cwd=work_dir)
            stack.enter_context(_started(node, stop_timeout=15.0))
        listener = Listener(spec)
        stack.callback(listener.close)
        node_alive = node.running if node is not None else (lambda: True)
        try:
            _measure(spec, work_dir, result, node, listener, node_alive,
                     discovery_timeout, drain_timeout, log)
        except (TimeoutError, RuntimeError) as e:
            result.error = str(e)
            if node is not None:
                result.error += f"\n--- calibrator.log ---\n{node.tail(20)}"
            log(f"  ERROR: {result.error}")
    if node is not None:
        result.node_exit = node.proc.returncode
        result.node_killed = node.killed
    result.load_after = os.getloadavg()
    return result


def _measure(spec: LoadSpec, work_dir: Path, result: LoadResult, node: NodeProcess | None,
             listener: Listener, node_alive: Callable[[], bool], discovery_timeout: float,
             drain_timeout: float, log: Callable[[str], None]) -> None:
    """The run proper, once the node (if any) and the listener exist; fills ``result``."""
    if node is not None:
        # The node must have found our subscribers before the stream starts (it draws no
        # overlay while nobody listens), and its diagnostics prove it is spinning.
        wait_for(listener.matched, discovery_timeout, "the node's overlay and diagnostics",
                 node_alive)
        wait_for(listener.last_diagnostics, discovery_timeout, "the node's first diagnostics",
                 node_alive)
    job = {"frames": str(work_dir / "frames.npy"), "topic": spec.image_topic,
           "encoding": spec.encoding, "rate_hz": spec.rate_hz, "seconds": spec.seconds,
           "reliable": spec.reliable, "depth": spec.depth,
           "subscribers": 0 if spec.alone else 1,
           "discovery_timeout": discovery_timeout, "result": str(work_dir / "sent.json")}
    (work_dir / "publisher.json").write_text(json.dumps(job))
    with contextlib.suppress(FileNotFoundError):
        (work_dir / "sent.json").unlink()
    publisher = NodeProcess.python_module("bench.node_load",
                                          ["--publisher", str(work_dir / "publisher.json")],
                                          work_dir / "publisher.log", name="publisher",
                                          cwd=work_dir)
    samples: list[tuple[int, int]] = []  # (time ns, VmRSS kB)
    with _started(publisher, stop_timeout=10.0):
        deadline = time.monotonic() + discovery_timeout + spec.seconds + 60.0
        while publisher.running():
            if node is not None:
                kb = vm_rss_kb(node.proc.pid)
                if kb is not None:
                    samples.append((time.time_ns(), kb))
                if not node.running():
                    raise RuntimeError(f"the node died during the stream (exit "
                                       f"{node.proc.returncode})")
            if time.monotonic() > deadline:
                raise TimeoutError("the publisher did not finish in time:\n"
                                   + publisher.tail(10))
            time.sleep(1.0)
    try:
        sent = json.loads((work_dir / "sent.json").read_text())
    except FileNotFoundError:
        raise RuntimeError("the publisher wrote no result:\n" + publisher.tail(10)) from None
    if sent.get("error"):
        raise RuntimeError(f"publisher: {sent['error']}")
    start_ns, end_ns = int(sent["start_ns"]), int(sent["end_ns"])
    result.sent = int(sent["sent"])
    # The stream spans ``seconds`` (its last frame is sent one interval before the end).
    result.stream_s = max((end_ns - start_ns) * 1e-9, spec.seconds)
    result.publish_ms = sent.get("publish_ms")
    result.late_ticks = int(sent.get("late_ticks", 0))
    log(f"  sent {result.sent} frames in {result.stream_s:.1f} s "
        f"({result.sent / result.stream_s:.1f} Hz; {result.late_ticks} late)")

    if node is not None:
        # Drain: the stream is over once every frame seen is accounted for (no frame waiting
        # in the node's slot, none in detection), in a report made after the stream ended.
        def drained() -> dict[str, str] | None:
            values = listener.last_diagnostics(after_ns=end_ns + 1_000_000_000)
            if values is None:
                return None
            done = sum(int(values.get(k, "0")) for k in (
                "frames processed", "frames dropped (busy)", "frames broken", "frames failed"))
            return values if done >= int(values.get("frames seen", "0")) else None

        try:
            wait_for(drained, drain_timeout, "the node to finish its last frame", node_alive,
                     period=0.2)
            result.drained = True
            time.sleep(1.0)  # the last overlay follows the count by a draw and a send
        except TimeoutError:
            log(f"  the node had not finished its last frame {drain_timeout:g} s after the "
                "stream")
        kb = vm_rss_kb(node.proc.pid)
        if kb is not None:
            samples.append((time.time_ns(), kb))
        result.diagnostics = dict(listener.last_diagnostics() or {})
        try:
            result.calibrate_s, result.calibrate_success, result.calibrate_message = \
                listener.call_trigger(f"/{spec.node_name}/calibrate", timeout=300.0)
        except TimeoutError as e:
            result.calibrate_message = str(e)
    result.rss_kb = [((t - start_ns) * 1e-9, kb) for t, kb in samples]
    with listener.lock:
        received = list(listener.reliable)
        result.overlays_best_effort = listener.best_effort
    result.overlays_reliable = len(received)
    result.latency = [((stamp - start_ns) * 1e-9, (recv - stamp) * 1e-9)
                      for recv, stamp, _, _, _ in received]
    if received:
        _, _, w, h, nbytes = received[-1]
        result.overlay_size, result.overlay_bytes = (w, h), nbytes


# --- the report -----------------------------------------------------------------------
def _f(value: float | None, fmt: str = ".2f", suffix: str = "") -> str:
    return "-" if value is None else f"{value:{fmt}}{suffix}"


def frames_table(results: Sequence[LoadResult]) -> str:
    """Markdown: frames sent, seen, processed, dropped, broken, lost, overlays."""
    lines = ["| frames | publisher | node's image qos | transport | rate Hz (sent) | s | sent "
             "| seen | processed | dropped (busy) | broken | lost before the node "
             "| missed (publisher sequence) | measured precisely | views "
             "| overlays reliable | overlays best effort |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        s = r.spec
        seen = r.count("frames seen")
        lost = None if seen is None else r.sent - seen
        achieved = r.sent / r.stream_s if r.stream_s else None
        lines.append(
            f"| {s.width}x{s.height} {s.encoding} ({r.frame_bytes / 1e6:.1f} MB) "
            f"| {'reliable' if s.reliable else 'best effort'} "
            f"| {r.diagnostics.get('image qos', '-')} "
            f"| {r.transport} | {s.rate_hz:g} ({_f(achieved, '.1f')}) | {s.seconds:g} | {r.sent} "
            f"| {_f(seen, 'd')} | {_f(r.count('frames processed'), 'd')} "
            f"| {_f(r.count('frames dropped (busy)'), 'd')} | {_f(r.count('frames broken'), 'd')} "
            f"| {_f(lost, 'd')} | {_f(r.count('frames missed (publisher sequence)'), 'd')} "
            f"| {_f(r.count('frames measured'), 'd')} "
            f"| {_f(r.count('views'), 'd')} | {r.overlays_reliable} | {r.overlays_best_effort} |")
    return "\n".join(lines)


def timing_table(results: Sequence[LoadResult]) -> str:
    """Markdown: latency, detection time, memory, the calibrate call, the load."""
    lines = ["| frames | detect here s | s a frame in the node | latency median / p95 s "
             "| first / last 10 s median s "
             "| VmRSS 10 s -> end MB (growth) | peak 10-20 s / last 10 s MB | ~/calibrate "
             "| node exit (SIGINT) | load before / after |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        s = r.spec
        med, p95 = r.latency_stats()
        first, last = r.latency_first_last()
        warm, end = r.rss_warm_end()
        growth = None if warm is None or end is None else 100.0 * (end - warm) / warm
        memory = (f"{_f(warm and warm / 1024, '.0f')} -> {_f(end and end / 1024, '.0f')} "
                  f"({_f(growth, '+.1f', ' %')})")
        early, late = r.rss_peaks()
        peaks = f"{_f(early and early / 1024, '.0f')} / {_f(late and late / 1024, '.0f')}"
        if r.calibrate_s is None:
            calibrate = r.calibrate_message or "-"
        else:
            answer = "ok" if r.calibrate_success else "refused"
            calibrate = f"{r.calibrate_s:.2f} s, {answer}: {r.calibrate_message[:70]}"
        lines.append(
            f"| {s.width}x{s.height} @ {s.rate_hz:g} Hz, {r.transport} | {_f(r.detect_s)} "
            f"| {_f(r.node_frame_s())} "
            f"| {_f(med)} / {_f(p95)} | {_f(first)} / {_f(last)} | {memory} | {peaks} "
            f"| {calibrate} "
            f"| {r.node_exit}{' (killed)' if r.node_killed else ''} "
            f"| {r.load_before[0]:.1f} / {r.load_after[0]:.1f} |")
    return "\n".join(lines)


def overlay_note(results: Sequence[LoadResult]) -> str:
    """The overlay message sizes received, against the full-size frames."""
    parts = []
    for r in results:
        if r.overlay_size is None:
            continue
        w, h = r.overlay_size
        full = r.spec.width * r.spec.height * 3
        parts.append(f"{r.spec.width}x{r.spec.height}: overlay {w}x{h}x3 = "
                     f"{r.overlay_bytes / 1e6:.2f} MB (full size would be {full / 1e6:.2f} MB)")
    return "; ".join(parts) + f" (overlay.max_width = {OVERLAY_MAX_WIDTH} caps the width)"


def dds_table(results: Sequence[LoadResult]) -> str:
    """Markdown: the --dds-only runs (frames to a subscriber here, no node)."""
    lines = ["| frames | transport | rate Hz (sent) | sent | received | latency median / p95 s "
             "| publish() ms | load |", "|---|---|---|---|---|---|---|---|"]
    for r in results:
        med, p95 = r.latency_stats()
        achieved = r.sent / r.stream_s if r.stream_s else None
        lines.append(f"| {r.spec.width}x{r.spec.height} {r.spec.encoding} | {r.transport} "
                     f"| {r.spec.rate_hz:g} ({_f(achieved, '.1f')}) | {r.sent} "
                     f"| {r.overlays_reliable} | {_f(med, '.3f')} / {_f(p95, '.3f')} "
                     f"| {_f(r.publish_ms)} | {r.load_before[0]:.1f} |")
    return "\n".join(lines)


def publisher_table(pairs: Sequence[tuple[LoadResult, LoadResult]]) -> str:
    """Markdown: the publisher's rate and publish() time with the node, and with nobody."""
    lines = ["| frames | publisher | rate Hz with the node / alone | change "
             "| publish() median ms with the node / alone | late ticks with / alone |",
             "|---|---|---|---|---|---|"]
    for with_node, alone in pairs:
        s = with_node.spec
        a = with_node.sent / with_node.stream_s if with_node.stream_s else None
        b = alone.sent / alone.stream_s if alone.stream_s else None
        change = None if a is None or not b else 100.0 * (a - b) / b
        lines.append(f"| {s.width}x{s.height} {s.encoding} @ {s.rate_hz:g} Hz "
                     f"| {'reliable' if s.reliable else 'best effort'} "
                     f"| {_f(a, '.2f')} / {_f(b, '.2f')} | {_f(change, '+.1f', ' %')} "
                     f"| {_f(with_node.publish_ms)} / {_f(alone.publish_ms)} "
                     f"| {with_node.late_ticks} / {alone.late_ticks} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.node_load",
                                     description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--width", type=int, help="frame width, pixels")
    parser.add_argument("--height", type=int, help="frame height, pixels")
    parser.add_argument("--rate", type=float, help="frames per second")
    parser.add_argument("--seconds", type=float, help="stream length, seconds")
    parser.add_argument("--encoding", help="mono8 | mono16 | bgr8 | rgb8 (default mono8; the "
                        "full set: each run's own)")
    parser.add_argument("--views", type=int, default=16, help="distinct rendered views")
    parser.add_argument("--fastdds-profile", type=Path,
                        help="a Fast DDS XML profile for every process of the run (e.g. "
                        "artcal_ros/ros/fastdds_large_shm.xml); default: Fast DDS's built-in "
                        "transports, the node its own large segment")
    parser.add_argument("--node-default-transport", action="store_true",
                        help="the node without its own large segment (Fast DDS's defaults)")
    parser.add_argument("--reliable", action="store_true", help="publish RELIABLE")
    parser.add_argument("--depth", type=int, default=5, help="publisher history depth")
    parser.add_argument("--dds-only", action="store_true",
                        help="no node: this process subscribes to the frames itself")
    parser.add_argument("--alone", action="store_true",
                        help="no node and no subscriber: the publisher's own rate")
    parser.add_argument("--no-baseline", action="store_true",
                        help="skip timing the detector in this process")
    parser.add_argument("--quick", action="store_true", help="one short 640x480 run")
    parser.add_argument("--json", type=Path, help="also write the results here")
    parser.add_argument("--keep", type=Path, help="work directory to keep (logs, frames)")
    parser.add_argument("--publisher", type=Path, help=argparse.SUPPRESS)  # the child
    args = parser.parse_args(argv)
    if args.publisher is not None:
        return publisher_main(args.publisher)

    given = (args.width, args.height, args.rate, args.seconds)
    full = not args.quick and all(v is None for v in given)
    runs: list[tuple[Any, ...]]
    if full:
        runs = [r if args.encoding is None else (*r[:4], args.encoding, args.reliable)
                for r in FULL_RUNS]
    else:
        base = QUICK_RUN
        runs = [(*(b if v is None else v for v, b in zip(given, base, strict=True)),
                 args.encoding or "mono8", args.reliable)]
    # Before any rclpy context exists here: the node and the publisher inherit it.
    if "ROS_DOMAIN_ID" not in os.environ:
        os.environ.update(private_domain_env())
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    if args.fastdds_profile is not None:
        os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = str(args.fastdds_profile.resolve())
    if args.node_default_transport:
        os.environ["ARTCAL_FASTDDS_PROFILE"] = "0"
    results = []
    with contextlib.ExitStack() as stack:
        root = args.keep or Path(stack.enter_context(tempfile.TemporaryDirectory(
            prefix="artcal_node_load_")))
        # the node saves its session (and ROS its logs) under $HOME/.ros: keep the user's own
        # ~/.ros/artcal/camera out of a benchmark
        home = root / "home"
        home.mkdir(parents=True, exist_ok=True)
        os.environ["HOME"] = str(home)
        pairs = []
        for w, h, rate, seconds, encoding, reliable in runs:
            spec = LoadSpec(int(w), int(h), float(rate), float(seconds), encoding,
                            views=args.views, reliable=reliable, depth=args.depth,
                            node=not (args.dds_only or args.alone), alone=args.alone,
                            baseline=not (args.no_baseline or args.dds_only or args.alone))
            print(f"{w}x{h} {encoding} at {rate:g} Hz for {seconds:g} s, "
                  f"{'reliable' if reliable else 'best effort'} publisher "
                  f"(load {os.getloadavg()[0]:.1f}, domain {os.environ['ROS_DOMAIN_ID']})",
                  flush=True)
            name = f"{w}x{h}_{encoding}_{rate:g}hz"
            results.append(run_load(spec, root / name))
            if full and spec.node:
                print("  the same stream with nobody subscribed", flush=True)
                alone = replace(spec, node=False, alone=True, baseline=False)
                # the frames the run just sent, as it saved them
                sent = np.load(root / name / "frames.npy")
                pairs.append((results[-1], run_load(alone, root / f"{name}_alone",
                                                    frames=list(sent))))
    print()
    if args.dds_only or args.alone:
        print(dds_table(results))
    else:
        print(frames_table(results))
        print()
        print(timing_table(results))
        print()
        print(overlay_note(results))
    if pairs:
        print()
        print(publisher_table(pairs))
    if args.json:
        args.json.write_text(json.dumps([asdict(r) for r in results], indent=1))
    failed = [r for r in results if r.error or r.node_killed]
    for r in failed:
        print(f"\n{r.spec.width}x{r.spec.height}: {r.error or 'the node ignored SIGINT'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
