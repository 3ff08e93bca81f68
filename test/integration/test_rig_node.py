"""The calibrator node with ``cameras: [left, right]`` over real DDS, started as the real
console script, fed rendered stereo frames of a known rig.

Checked against the renderer's truth: both CameraInfos (the right one's P with
Tx = -fx' * baseline), the baseline within 1 % of the true 0.12 m, the files written, the
rig's diagnostics and overlays, the live readiness (each camera's projection uncertainty in
the diagnostics, ``ready`` turning true once every camera's is within the bound, near the
true projection difference), both drivers' set_camera_info called (commit), ~/reset; one
camera name alone is refused at start-up, naming the parameter.
"""

from __future__ import annotations

import json
import re
import threading
import time
from collections.abc import Callable, Iterator
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo
from std_srvs.srv import Trigger

from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.camera import CameraModel
from test.integration.qos import LATCHED, RELIABLE
from test.integration.ros_harness import PARAMS, NodeProcess, Probe, wait_until

pytestmark = pytest.mark.integration

N_FRAMES = 12      # rig poses rendered, published round and round
MIN_VIEWS = 8      # rig views before ~/calibrate solves
MAX_UNCERTAINTY = 0.1  # px, readiness.max_uncertainty (config/calibrator.yaml's)
TIGHT_UNCERTAINTY = 0.002  # px, a bound these 12 poses cannot reach (they give ~0.015 px)
UNCERTAINTY = re.compile(r"(\d+\.\d+) px RMS, max \d+\.\d+ px \((\d+) views\)")
PERIOD_S = 0.35    # between rig frames: the node measures about every one of them
BASELINE_M = 0.12  # the stereo rig preset's


def rig_node(tmp_path: Path, name: str, *params: str) -> NodeProcess:
    """The calibrator console script as node ``name`` with config/calibrator.yaml and
    ``params`` (``key:=value``) on top; its files go to ``tmp_path``."""
    args = ["--params-file", str(PARAMS), "-r", f"__node:={name}",
            "-p", f"output_file:={tmp_path / 'unused.yaml'}"]
    for p in params:
        args += ["-p", p]
    return NodeProcess("calibrator", args, tmp_path, name=name)


class StereoFrames:
    """Rendered 640x480 bgr8 stereo frames of the stereo rig preset, with the rig."""

    def __init__(self, n: int, seed: int = 25) -> None:
        from std_msgs.msg import Header

        from artcal_ros.core.board import Board
        from artcal_ros.ros.msgs import bgr8_image
        from artcal_ros.synth import Camera
        from artcal_ros.synth.rig import Rig, rig_poses
        from artcal_ros.synth.view import render_view

        board = Board()
        self.rig = Rig.preset("stereo", Camera.preset("webcam"))
        poses = rig_poses(board, self.rig, n, np.random.default_rng(seed))
        self.images: list[dict[str, Any]] = []
        for i, pose in enumerate(poses):
            frame = {}
            for k, cam_name in enumerate(self.rig.names):
                view = render_view(board, self.rig.camera(cam_name),
                                   *self.rig.camera_pose(cam_name, pose),
                                   rng=np.random.default_rng([seed, i, k]), encoding="bgr8")
                frame[cam_name] = bgr8_image(view.image, Header(frame_id=f"{cam_name}_optical"))
            self.images.append(frame)


@pytest.fixture(scope="module")
def stereo() -> StereoFrames:
    return StereoFrames(N_FRAMES)


class StereoStreamer:
    """Publishes the frames on left/image and right/image round and round, stamped now
    (right 3 ms after left, within sync_tolerance), one rig frame every PERIOD_S."""

    def __init__(self, probe: Probe, frames: StereoFrames, namespace: str = "") -> None:
        self.node = probe.node
        self.pubs = {n: probe.node.create_publisher(Image, f"{namespace}/{n}/image", RELIABLE)
                     for n in frames.rig.names}
        self.frames = frames
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        k = 0
        while not self._stop.wait(PERIOD_S):
            now = time.time_ns()
            for j, (n, pub) in enumerate(self.pubs.items()):
                msg = self.frames.images[k % len(self.frames.images)][n]
                stamp = now + j * 3_000_000
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
                pub.publish(msg)
            k += 1

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(5.0)
        for pub in self.pubs.values():
            # through the node: a publisher destroyed behind its back stays in the node's list
            # and every later wait of the shared probe's executor fails on its handle
            self.node.destroy_publisher(pub)


@pytest.fixture
def streamer(probe: Probe, stereo: StereoFrames) -> Iterator[StereoStreamer]:
    s = StereoStreamer(probe, stereo)
    yield s
    s.stop()


def calibrate_until_success(probe: Probe, service: str, timeout: float) -> Any:
    """Call ``service`` (Trigger) every few seconds until it answers success."""
    answers: list[str] = []

    def attempt() -> Any:
        answer = probe.call(Trigger, service, timeout=60.0)
        answers.append(answer.message)
        return answer if answer.success else None

    try:
        return wait_until(attempt, timeout, f"a successful {service}", period=3.0)
    except AssertionError as e:
        raise AssertionError(f"{e}; answers: {answers[-3:]}") from None


def rig_status(arrays: list[Any], node: str, part: str) -> dict[str, str]:
    """The newest key/values of the status ``<node>: <part>``."""
    for array in reversed(list(arrays)):
        for status in array.status:
            if status.name == f"{node}: {part}":
                return {kv.key: kv.value for kv in status.values}
    return {}


def test_stereo_stream_calibrates_the_rig(tmp_path: Path, probe: Probe,
                                         stereo: StereoFrames,
                                         streamer: StereoStreamer) -> None:
    t0 = time.monotonic()
    infos = {n: probe.collect(CameraInfo, f"/{n}/camera_info", LATCHED) for n in ("left",
                                                                                  "right")}
    diags = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    overlays = {n: probe.collect(Image, f"/rigcal/{n}/overlay", RELIABLE)
                for n in ("left", "right")}
    # the drivers' set_camera_info, which commit calls
    committed: dict[str, list[CameraInfo]] = {"left": [], "right": []}

    def serve(name: str, request: Any, response: Any) -> Any:
        committed[name].append(request.camera_info)
        response.success = True
        return response

    services = [probe.node.create_service(SetCameraInfo, f"/{n}/set_camera_info",
                                          partial(serve, n)) for n in committed]
    node = rig_node(tmp_path, "rigcal", "cameras:=[left,right]", f"min_views:={MIN_VIEWS}",
                    "commit:=true", f"report_dir:={tmp_path / 'report'}",
                    f"readiness.max_uncertainty:={TIGHT_UNCERTAINTY}")
    try:
        # enough rig views, but the cameras not yet known within the bound: not ready
        short = wait_rig(diags, lambda rig: int(rig["rig views"]) >= MIN_VIEWS and all(
            UNCERTAINTY.fullmatch(rig[f"{n}: projection uncertainty"]) for n in ("left", "right"))
            and f"needs <= {TIGHT_UNCERTAINTY:.3g} px" in rig["missing"], 120.0,
            "enough rig views, the uncertainty over a tight bound")
        assert short["ready"] == "false", short
        print(f"not ready at {short['rig views']} rig views: {short['missing']}")
        set_parameter(probe, "rigcal", "readiness.max_uncertainty", MAX_UNCERTAINTY)
        ready = wait_rig(diags, lambda rig: rig["ready"] == "true" and all(
            UNCERTAINTY.fullmatch(c.get("projection uncertainty", "")) and c.get("next pose")
            for c in (rig_status(diags, "rigcal", n) for n in ("left", "right"))), 60.0,
            "the live rig ready")
        answer = calibrate_until_success(probe, "/rigcal/calibrate", timeout=80.0)
    finally:
        for service in services:
            probe.node.destroy_service(service)
    assert "left -> right: baseline" in answer.message, answer.message
    # every rig view is one instant of both cameras: a view pairing two instants would bring
    # hundreds of outlier points (the rendered frames have none)
    assert int(re.search(r"(\d+) outlier points", answer.message).group(1)) < 50, answer.message
    assert "committed to /left/set_camera_info, /right/set_camera_info" in answer.message, \
        answer.message
    wait_until(lambda: infos["left"] and infos["right"], 20.0, "both camera_info messages")
    for n in committed:
        assert len(committed[n]) == 1 and list(committed[n][0].p) == list(infos[n][-1].p)
    left, right = infos["left"][-1], infos["right"][-1]
    assert (left.header.frame_id, right.header.frame_id) == ("left_optical", "right_optical")
    for info, name in ((left, "left"), (right, "right")):
        assert (info.width, info.height) == (640, 480)
        true_K = stereo.rig.camera(name).K
        K = np.asarray(info.k).reshape(3, 3)
        assert abs(K[0, 0] / true_K[0, 0] - 1) < 0.01, (name, K, true_K)
        assert np.allclose(np.asarray(info.r).reshape(3, 3) @ np.asarray(info.r).reshape(3, 3).T,
                           np.eye(3), atol=1e-9)
    P_left, P_right = np.asarray(left.p).reshape(3, 4), np.asarray(right.p).reshape(3, 4)
    assert P_left[0, 3] == 0.0
    assert np.allclose(P_left[:, :3], P_right[:, :3])  # one rectified camera for both
    baseline = -P_right[0, 3] / P_right[0, 0]           # Tx = -fx' * baseline
    assert abs(baseline / BASELINE_M - 1) < 0.01, baseline
    for f in ("left.yaml", "right.yaml", "camchain.yaml"):
        assert (tmp_path / f).is_file(), f
    written = yaml.safe_load((tmp_path / "right.yaml").read_text())
    assert np.allclose(written["projection_matrix"]["data"], right.p)
    rig = wait_until(lambda: rig_status(diags, "rigcal", "rig").get("rig views"), 10.0,
                     "the rig's diagnostics")
    status = rig_status(diags, "rigcal", "rig")
    assert int(rig) >= MIN_VIEWS and int(status["shared views left-right"]) >= MIN_VIEWS, status
    assert int(rig_status(diags, "rigcal", "left")["frames seen"]) > 0
    for n in ("left", "right"):
        wait_until(lambda n=n: overlays[n], 10.0, f"{n}'s overlay")
        assert (overlays[n][-1].encoding, overlays[n][-1].width) == ("bgr8", 640)
    cleared = probe.call(Trigger, "/rigcal/reset")
    # "cleared N rig views": every view of the solve at least (the stream goes on)
    assert cleared.success and int(cleared.message.split()[1]) >= int(rig), cleared.message
    assert node.running()
    # the rig's report, written after the answer into report_dir
    assert f"report: {tmp_path / 'report'}" in answer.message, answer.message
    wait_until(lambda: "report written" in node.output(), 120.0, "the rig's report")
    assert (tmp_path / "report" / "report.pdf").read_bytes().startswith(b"%PDF")
    summary = json.loads((tmp_path / "report" / "summary.json").read_text())
    assert summary["extrinsics"][0]["from"] == "left", summary.keys()
    assert "Traceback" not in node.output()
    # the live readiness: before the rig views were in, not ready and saying why
    first = next(rig_status([a], "rigcal", "rig") for a in list(diags)
                 if rig_status([a], "rigcal", "rig"))
    assert first["ready"] == "false" and "more rig views" in first["missing"], first
    # when ready: each camera's uncertainty within the bound, near its true difference
    # (of the final solve, from more views: the same camera within a few x)
    for n, info in ((n, infos[n][-1]) for n in ("left", "right")):
        m = UNCERTAINTY.fullmatch(ready[f"{n}: projection uncertainty"])
        assert m, ready
        uncertainty = float(m.group(1))
        assert uncertainty <= MAX_UNCERTAINTY and int(m.group(2)) >= 3, ready
        assert f"\n{n}: ready: projection uncertainty" in answer.message \
            or f"\n{n}: not ready yet" in answer.message, answer.message
        true = projection_difference(stereo.rig.camera(n), CameraModel(
            "plumb_bob", np.asarray(info.k).reshape(3, 3), np.asarray(info.d),
            (info.width, info.height)))[0]
        assert 0.1 < true / uncertainty < 10, (n, true, uncertainty)
        print(f"{n}: live projection uncertainty {uncertainty:.4f} px at ready "
              f"({ready['rig views']} rig views), final solve's true difference {true:.4f} px")
    print(f"stereo node: calibrated in {time.monotonic() - t0:.1f} s, baseline "
          f"{baseline:.5f} m")


def wait_rig(diags: list[Any], predicate: Callable[[dict[str, str]], bool], timeout: float,
             what: str) -> dict[str, str]:
    """The newest rig status once ``predicate`` holds for it; AssertionError with the last
    statuses."""
    def newest() -> dict[str, str] | None:
        rig = rig_status(diags, "rigcal", "rig")
        return rig if rig and predicate(rig) else None

    try:
        return wait_until(newest, timeout, what, period=0.2)
    except AssertionError as e:
        statuses = {p: rig_status(diags, "rigcal", p) for p in ("rig", "left", "right")}
        raise AssertionError(f"{e}; last statuses: {statuses}") from None


def set_parameter(probe: Probe, node: str, name: str, value: float) -> None:
    """Set a double parameter of ``/node`` through its set_parameters service."""
    request = SetParameters.Request(parameters=[ParameterMsg(name=name, value=ParameterValue(
        type=ParameterType.PARAMETER_DOUBLE, double_value=value))])
    answer = probe.call(SetParameters, f"/{node}/set_parameters", request)
    assert answer.results[0].successful, answer.results[0].reason


def test_one_camera_name_is_refused(tmp_path: Path) -> None:
    node = rig_node(tmp_path, "rig_bad", "cameras:=[left]")
    rc = node.wait(30)
    text = node.output()
    assert rc == 2, text
    assert "parameter 'cameras'" in text and "names one camera" in text, text
    assert "Traceback" not in text, text


RIG_THREADS = {"measure rig views", "live solve", "spin executor"}


def test_no_rig_node_thread_outlives_stop(tmp_path: Path, probe: Probe,
                                         stereo: StereoFrames) -> None:
    # In process: the rig node's threads (the rig stream's, each camera's live solve) run
    # while it collects, and none is left once its stop() and shut_down() returned.
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import MultiThreadedExecutor

    from artcal_ros.ros.rig_calibrator import RigCalibratorNode
    from artcal_ros.ros.signals import ExecutorSpin, shut_down

    name = "rig_threads"
    before = set(threading.enumerate())
    context = Context()
    rclpy.init(args=["--ros-args", "-r", f"__ns:=/{name}", "-p", "cameras:=[left,right]",
                     "-p", "min_views:=3", "-p", f"output_file:={tmp_path / 'unused.yaml'}"],
               context=context)
    try:
        node = RigCalibratorNode(node_name=name, context=context)
        executor = MultiThreadedExecutor(num_threads=4, context=context)
        executor.add_node(node)
        spin = ExecutorSpin(executor)
        running = [t for t in threading.enumerate() if t not in before]
        assert sorted(t.name for t in running if t.name == "live solve") == ["live solve"] * 2
        assert {t.name for t in running} >= RIG_THREADS, running
        streamer = StereoStreamer(probe, stereo, namespace=f"/{name}")
        try:
            # every camera's live solve made an estimate of its views
            wait_until(lambda: all(s.estimate is not None
                                   for s in node.status.cameras.values()), 120.0,
                       "both cameras' live estimates")
        finally:
            streamer.stop()
        assert node.stop(timeout=10.0) == []
        shut_down(node, spin)
    finally:
        rclpy.try_shutdown(context=context)
    left = sorted(t.name for t in running if t.is_alive() and t.name in RIG_THREADS)
    assert left == [], f"threads outlived the rig node's stop: {left}"
