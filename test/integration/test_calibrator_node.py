"""The calibrator node over real DDS, started as the real console script.

Checked against the bag's ground truth: a recording played by the replay node calibrates
to the true camera; reliable and best-effort publishers both reach the node; malformed
frames are counted and skipped while good ones still calibrate; CameraInfo reaches a late
transient-local subscriber; ~/reset clears; commit calls set_camera_info; SIGINT during a
solve exits promptly; bad parameters refuse start-up naming the parameter.
"""

from __future__ import annotations

import json
import re
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from sensor_msgs.msg import CameraInfo, CompressedImage, Image
from sensor_msgs.srv import SetCameraInfo
from std_srvs.srv import Trigger

from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.camera import CameraModel
from test.integration.frames import CalibrationBag, image_messages
from test.integration.qos import BEST_EFFORT, LATCHED, RELIABLE
from test.integration.ros_harness import (
    PARAMS,
    NodeProcess,
    Probe,
    diagnostics_values,
    wait_until,
)
from test.integration.streaming import publish_until, send_until_counted

pytestmark = pytest.mark.integration

MIN_VIEWS = 10  # config/calibrator.yaml
# Clean synthetic frames calibrate to within ~0.1-0.3 px of the true camera over the whole
# image (projection difference, RMS). 1 px is where a calibration starts to be visibly
# wrong when rectifying; a solve that lost a parameter or mixed up views is off by tens.
ACCURACY_RMS_PX = 1.0


def calibrator(tmp_path: Path, name: str, image_topic: str, *params: str,
               remaps: tuple[str, ...] = (), per_test: bool = True) -> NodeProcess:
    """The calibrator node under ``name``, listening on ``image_topic``."""
    args = ["--params-file", str(PARAMS), "-r", f"__node:={name}", "-r", f"image:={image_topic}",
            "-p", f"output_file:={tmp_path / (name + '.yaml')}"]
    for p in params:
        args += ["-p", p]
    for r in remaps:
        args += ["-r", r]
    return NodeProcess("calibrator", args, tmp_path, name=name, per_test=per_test)


def stop_cleanly(node: NodeProcess) -> None:
    rc = node.stop()
    assert rc in (0, -2, 130), f"exit {rc}\n{node.output()[-3000:]}"
    assert "Traceback" not in node.output(), node.output()


def set_parameter(probe: Probe, node_name: str, name: str, value: bool) -> None:
    request = SetParameters.Request(parameters=[ParameterMsg(
        name=name, value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=value))])
    answer = probe.call(SetParameters, f"/{node_name}/set_parameters", request)
    assert answer.results[0].successful, answer.results[0].reason


def camera_info_accuracy(info: CameraInfo, truth: Any) -> float:
    """RMS projection difference (pixels) between the published camera and the truth."""
    estimate = CameraModel(info.distortion_model, np.array(info.k).reshape(3, 3),
                           np.array(info.d), (info.width, info.height))
    rms, _ = projection_difference(truth, estimate)
    return rms


def test_bag_replayed_into_the_node_calibrates_to_the_truth(
        tmp_path: Path, probe: Probe, bag: CalibrationBag) -> None:
    node = calibrator(tmp_path, "cal_e2e", "/e2e/image")
    overlay = probe.collect(Image, "/cal_e2e/overlay", RELIABLE)
    coverage = probe.collect(Image, "/cal_e2e/coverage", LATCHED)
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    # At the recorded speed: the node tracks every frame and measures the new views in the
    # background (loop in case a loaded machine drops some anyway).
    replay = NodeProcess("replay", ["-p", f"bag:={bag.path}", "-p", "rate:=1.0",
                                    "-p", "loop:=true",
                                    "-r", f"{bag.topic}:=/e2e/image"], tmp_path)
    try:
        wait_until(lambda: overlay and coverage, 60, "the first overlay and coverage images")
        first = overlay[0]
        assert first.encoding == "bgr8"
        assert (first.width, first.height) == bag.camera.size
        wait_until(lambda: int(diagnostics_values(diagnostics, "cal_e2e").get("views", 0))
                   >= MIN_VIEWS, 150, f"{MIN_VIEWS} views collected")
    finally:
        stop_cleanly(replay)
    def accounted() -> dict[str, str] | None:
        v = diagnostics_values(diagnostics, "cal_e2e")
        done = sum(int(v[k]) for k in ("frames processed", "frames dropped (busy)",
                                       "frames broken", "frames failed"))
        return v if done == int(v["frames seen"]) else None

    # Every frame received is processed, or dropped because a newer one came during a
    # detection (keep-latest), never queued: once the stream stops the counts add up.
    values = wait_until(accounted, 30, "every frame seen to be processed or dropped")
    assert int(values["frames seen"]) >= int(values["frames used"]) >= MIN_VIEWS
    assert int(values["frames measured"]) >= int(values["frames used"])
    assert int(values["frames broken"]) == 0
    assert float(values["coverage"]) > 0.3
    assert np.asarray(coverage[-1].data).any(), "the heat map shows the covered cells"

    reports_before = len(diagnostics)
    t0 = time.monotonic()
    answer = probe.call(Trigger, "/cal_e2e/calibrate", timeout=120)
    took = time.monotonic() - t0
    assert answer.success, answer.message
    if took > 2.5:  # the 1 Hz diagnostics timer kept running during the solve
        assert len(diagnostics) > reports_before, f"no diagnostics during a {took:.1f} s solve"
    for word in ("RMS", "fx", "fy", "cx", "cy", "views used"):
        assert word in answer.message
    # Subscribing only now: the transient-local CameraInfo must still arrive.
    infos = probe.collect(CameraInfo, "/camera_info", LATCHED)
    wait_until(lambda: infos, 20, "the latched CameraInfo")
    info = infos[-1]
    rms = camera_info_accuracy(info, bag.camera)
    assert rms < ACCURACY_RMS_PX, f"projection difference {rms:.3f} px; {answer.message}"
    saved = yaml.safe_load((tmp_path / "cal_e2e.yaml").read_text())
    np.testing.assert_allclose(saved["camera_matrix"]["data"], info.k, rtol=1e-6)
    assert (saved["image_width"], saved["image_height"]) == bag.camera.size

    cleared = probe.call(Trigger, "/cal_e2e/reset")
    assert cleared.success and "cleared" in cleared.message
    wait_until(lambda: not np.asarray(coverage[-1].data).any(), 10, "an empty heat map")
    refused = probe.call(Trigger, "/cal_e2e/calibrate")
    assert not refused.success
    assert "not enough views" in refused.message and f"views 0/{MIN_VIEWS}" in refused.message
    stop_cleanly(node)


# --- one node fed frame by frame from the test ------------------------------------------

def broken_copies(good: Image) -> list[tuple[str, Image]]:
    """Three malformed versions of a frame: wrong step, unknown encoding, truncated data."""
    def copy(**changes: Any) -> Image:
        msg = Image(header=good.header, height=good.height, width=good.width,
                    encoding=good.encoding, is_bigendian=good.is_bigendian, step=good.step,
                    data=bytes(good.data))
        for k, v in changes.items():
            setattr(msg, k, v)
        return msg

    return [("wrong step", copy(step=good.step - 1)),
            ("unknown encoding", copy(encoding="yuv_unheard_of")),
            ("truncated", copy(data=bytes(good.data)[: len(good.data) // 2]))]


FED_VIEWS = 6  # fewer than the default 10: each frame costs seconds of detection here


def fed_frames(bag: CalibrationBag) -> list[Image]:
    """FED_VIEWS + 2 frames spread over the recording (distinct views of a smooth sweep)."""
    frames = image_messages(bag)
    picks = np.linspace(0, len(frames) - 1, FED_VIEWS + 2).round().astype(int)
    return [frames[i] for i in picks]


class Fed:
    """The state shared by the tests of the frame-by-frame fed node."""

    def __init__(self, node: NodeProcess, overlay: list[Any], diagnostics: list[Any],
                 broken: int, base: dict[str, str]) -> None:
        self.node = node
        self.overlay = overlay
        self.diagnostics = diagnostics
        self.broken = broken
        self.base = base  # diagnostics after the warm-up frames

    def count(self, key: str) -> int:
        """A diagnostics counter, less its value after the warm-up."""
        now = diagnostics_values(self.diagnostics, "cal_fed")
        return int(now[key]) - int(self.base[key])


def warm_up(publisher: Any, msg: Image, overlay: list[Any], what: str) -> None:
    """Send ``msg`` until its overlay comes back: discovery is two-sided and a match seen
    here may not be seen by the node yet, so the first frames can be lost."""
    deadline = time.monotonic() + 60
    while True:
        before = len(overlay)
        publisher.publish(msg)
        try:
            wait_until(lambda b=before: len(overlay) > b, 20, what)
            return
        except AssertionError:
            if time.monotonic() > deadline:
                raise


@pytest.fixture(scope="module")
def fed(tmp_path_factory: pytest.TempPathFactory, probe: Probe,
        bag: CalibrationBag) -> Iterator[Fed]:
    """A node given every bag frame, alternately from a reliable and a best-effort publisher,
    with a malformed frame after every second good one; each frame is sent once the node
    has finished the previous one (its overlay came back), so none is dropped as busy."""
    tmp = tmp_path_factory.mktemp("fed")
    node = calibrator(tmp, "cal_fed", "/fed/image", f"min_views:={FED_VIEWS}",
                      f"report_dir:={tmp / 'report'}",
                      remaps=("set_camera_info:=/fake_camera/set_camera_info",),
                      per_test=False)
    overlay = probe.collect(Image, "/cal_fed/overlay", RELIABLE)
    diagnostics = probe.collect(DiagnosticArray, "/diagnostics", RELIABLE)
    reliable = probe.node.create_publisher(Image, "/fed/image", RELIABLE)
    best_effort = probe.node.create_publisher(Image, "/fed/image", BEST_EFFORT)
    frames = fed_frames(bag)
    broken = 0
    try:
        warm_up(reliable, frames[0], overlay, "the node to take frames from a reliable publisher")
        warm_up(best_effort, frames[0], overlay, "the node to take best-effort frames")
        warm = len(overlay)
        # Every processed good frame gives one overlay: equal counts mean none is pending.
        values = wait_until(lambda: (lambda v: v if v and int(v["frames processed"]) == warm
                                     == len(overlay) else None)(
                                         diagnostics_values(diagnostics, "cal_fed")),
                            20, "diagnostics of the warm-up frames")

        def seen() -> int:
            return int(diagnostics_values(diagnostics, "cal_fed").get("frames seen", 0))

        # Sent again only if the node did not receive it (a best-effort frame lost on a busy
        # machine), so the counts below stay exact.
        expected = int(values["frames seen"])
        for k, msg in enumerate(frames):
            before = len(overlay)
            kind = "reliable" if k % 2 == 0 else "best effort"
            expected += 1
            send_until_counted(reliable if k % 2 == 0 else best_effort, msg, seen, expected,
                               60, f"the node to receive frame {k} ({kind})")
            wait_until(lambda b=before: len(overlay) > b, 30, f"the overlay of frame {k}")
            if k % 2 == 1:
                kind, bad = broken_copies(msg)[broken % 3]
                expected += 1
                send_until_counted(reliable if broken % 2 == 0 else best_effort, bad, seen,
                                   expected, 60, f"the node to receive a {kind} frame")
                broken += 1
                wait_until(lambda n=broken: int(diagnostics_values(diagnostics, "cal_fed").get(
                    "frames broken", 0)) >= n, 10, f"a {kind} frame to be counted")
        yield Fed(node, overlay, diagnostics, broken, values)
    finally:
        probe.node.destroy_publisher(reliable)
        probe.node.destroy_publisher(best_effort)
        if node.proc.poll() is None:
            stop_cleanly(node)


def test_both_qos_reach_the_node_and_broken_frames_are_skipped(
        fed: Fed, probe: Probe, bag: CalibrationBag, tmp_path: Path) -> None:
    assert fed.broken >= 3, "every kind of malformed frame was sent"
    # Diagnostics come once a second: wait for the report that includes the last frame.
    sent = FED_VIEWS + 2
    wait_until(lambda: fed.count("frames processed") >= sent, 10, "diagnostics of every frame")
    assert fed.count("frames processed") == sent
    assert fed.count("frames broken") == fed.broken
    assert fed.count("frames seen") == sent + fed.broken
    assert fed.count("frames dropped (busy)") == 0
    # Every cause is named with its count in the diagnostics and logged once, however
    # many frames of it came (the first cause is sent twice).
    causes = diagnostics_values(fed.diagnostics, "cal_fed")["broken causes"]
    counts = dict(part.rsplit(": ", 1) for part in causes.split("; "))
    assert sum(int(n) for n in counts.values()) == fed.broken, causes
    assert len(counts) == 3 and "unknown encoding 'yuv_unheard_of'" in counts, causes
    assert max(int(n) for n in counts.values()) >= 2, causes
    logged = [line for line in fed.node.output().splitlines() if "skipping broken frames" in line]
    assert len(logged) == len(counts), "\n".join(logged)
    warned = [st for array in list(fed.diagnostics) for st in array.status
              if st.name.startswith("cal_fed:") and st.level == DiagnosticStatus.WARN]
    assert warned and "broken frames skipped" in warned[0].message
    answer = probe.call(Trigger, "/cal_fed/calibrate", timeout=120)
    assert answer.success, answer.message
    # The report is written on the solve thread after the answer, into report_dir.
    report = Path(answer.message.rsplit("report: ", 1)[1].split(";")[0].strip())
    assert report.name == "report" and report.parent.name.startswith("fed"), answer.message
    wait_until(lambda: "report written" in fed.node.output(), 120, "the report to be written")
    pdf = (report / "report.pdf").read_bytes()
    pages = len(re.findall(rb"/Type\s*/Page(?![a-zA-Z])", pdf))
    assert pdf.startswith(b"%PDF") and pages >= 6, pages
    for png in ("verdict.png", "residuals.png", "uncertainty.png", "distortion.png"):
        assert cv2.imread(str(report / png)) is not None, png
    summary = json.loads((report / "summary.json").read_text())
    assert summary["success"] and summary["projection_uncertainty_px"]["rms"] > 0


def test_commit_sends_the_result_to_set_camera_info(fed: Fed, probe: Probe) -> None:
    set_parameter(probe, "cal_fed", "commit", True)
    missing = probe.call(Trigger, "/cal_fed/calibrate", timeout=120)
    assert not missing.success and "NOT committed" in missing.message, missing.message
    received: list[CameraInfo] = []

    def serve(request: Any, response: Any) -> Any:
        received.append(request.camera_info)
        response.success = True
        return response

    service = probe.node.create_service(SetCameraInfo, "/fake_camera/set_camera_info", serve)
    try:
        answer = probe.call(Trigger, "/cal_fed/calibrate", timeout=120)
        assert answer.success and "committed" in answer.message, answer.message
        assert len(received) == 1 and received[0].k[0] > 0
    finally:
        probe.node.destroy_service(service)
        set_parameter(probe, "cal_fed", "commit", False)


def test_calibrate_parameters_set_at_run_time_shape_the_next_solve(fed: Fed,
                                                                  probe: Probe) -> None:
    # Out of range for plumb_bob: refused, naming the parameter and the allowed values.
    request = SetParameters.Request(parameters=[ParameterMsg(
        name="calibrate.k_coefficients",
        value=ParameterValue(type=ParameterType.PARAMETER_INTEGER, integer_value=7))])
    refused = probe.call(SetParameters, "/cal_fed/set_parameters", request).results[0]
    assert not refused.successful
    assert "calibrate.k_coefficients" in refused.reason and "1 to 3" in refused.reason
    infos = probe.collect(CameraInfo, "/camera_info", LATCHED)
    set_parameter(probe, "cal_fed", "calibrate.fix_aspect_ratio", True)
    set_parameter(probe, "cal_fed", "calibrate.zero_tangent_dist", True)
    try:
        answer = probe.call(Trigger, "/cal_fed/calibrate", timeout=120)
        assert answer.success, answer.message
        assert "fx = fy" in answer.message and "views used" in answer.message
        # The latched CameraInfo of an earlier solve may come first; wait for this one's.
        info = wait_until(lambda: next((i for i in reversed(infos) if i.k[0] == i.k[4]), None),
                          20, "a CameraInfo with fx = fy")
        assert info.d[2] == 0.0 and info.d[3] == 0.0  # p1 = p2 = 0
        assert f"fx = fy {info.k[0]:.2f}" in answer.message
        assert "calibrate.fix_aspect_ratio = True" in fed.node.output()
    finally:
        set_parameter(probe, "cal_fed", "calibrate.fix_aspect_ratio", False)
        set_parameter(probe, "cal_fed", "calibrate.zero_tangent_dist", False)


def set_string_parameter(probe: Probe, node_name: str, name: str, value: str) -> None:
    request = SetParameters.Request(parameters=[ParameterMsg(
        name=name, value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                        string_value=value))])
    answer = probe.call(SetParameters, f"/{node_name}/set_parameters", request)
    assert answer.results[0].successful, answer.results[0].reason


def test_an_unwritable_output_file_is_named_and_camera_info_still_published(
        fed: Fed, probe: Probe, tmp_path: Path) -> None:
    blocker = tmp_path / "a_file"
    blocker.write_text("a file where the output directory should be")
    target = blocker / "calibration" / "camera.yaml"
    infos = probe.collect(CameraInfo, "/camera_info", LATCHED)
    set_string_parameter(probe, "cal_fed", "output_file", str(target))
    try:
        called = time.time() - 1.0  # the node stamps CameraInfo with its (wall) clock
        answer = probe.call(Trigger, "/cal_fed/calibrate", timeout=120)
        assert not answer.success, answer.message
        assert str(target) in answer.message and "not a directory" in answer.message
        assert "NOT saved" in answer.message and "RMS" in answer.message, answer.message
        # A CameraInfo of an earlier solve may be latched; this one is stamped after the call.
        wait_until(lambda: any(i.header.stamp.sec + i.header.stamp.nanosec * 1e-9 > called
                               and i.k[0] > 0 for i in infos), 20,
                   "the CameraInfo of the unsaved calibration")
    finally:
        set_string_parameter(probe, "cal_fed", "output_file", str(tmp_path / "cal_fed.yaml"))


def test_sigint_during_a_solve_exits_promptly(fed: Fed, probe: Probe) -> None:
    client = probe.node.create_client(Trigger, "/cal_fed/calibrate")
    assert client.wait_for_service(timeout_sec=20)
    solves = fed.node.output().count("solving from")
    client.call_async(Trigger.Request())
    wait_until(lambda: fed.node.output().count("solving from") > solves, 30,
               "the solve to start")
    t0 = time.monotonic()
    rc = fed.node.stop(timeout=10)
    elapsed = time.monotonic() - t0
    assert rc in (0, -2, 130), fed.node.output()[-3000:]
    assert elapsed < 5.0, f"took {elapsed:.1f} s to stop"
    assert "Traceback" not in fed.node.output()
    probe.node.destroy_client(client)


def test_compressed_transport(tmp_path: Path, probe: Probe, bag: CalibrationBag) -> None:
    from artcal_ros.core.images import image_to_numpy

    node = calibrator(tmp_path, "cal_jpeg", "/cj/image", "image_transport:=compressed")
    overlay = probe.collect(Image, "/cal_jpeg/overlay", RELIABLE)
    pub = probe.node.create_publisher(CompressedImage, "/cj/image/compressed", RELIABLE)
    try:
        wait_until(lambda: pub.get_subscription_count()
                   and probe.node.count_publishers("/cal_jpeg/overlay"), 30, "the node")
        frame = image_messages(bag)[0]
        ok, png = cv2.imencode(".png", image_to_numpy(frame))
        assert ok
        # Repeated until the overlay comes: the node may not have matched us yet.
        publish_until(pub, CompressedImage(header=frame.header, format="mono8; png compressed",
                                           data=png.tobytes()),
                      lambda: overlay, 60, "the overlay of a compressed frame", every_s=3.0)
        assert (overlay[0].width, overlay[0].height) == bag.camera.size
    finally:
        probe.node.destroy_publisher(pub)
        stop_cleanly(node)


@pytest.mark.parametrize(("param", "name", "in_file"), [
    ("board.cols:=-1", "board.cols", False),
    ("camera_model:=pinhole", "camera_model", True),
    ("board.marker_length:=abc", "board.marker_length", True),
    ("max_views:=3", "max_views", False),
    ("calibrate.k_coefficients:=4", "calibrate.k_coefficients", False),
    ("image_qos:=sometimes", "image_qos", True),
])
def test_bad_parameter_refuses_to_start(tmp_path: Path, param: str, name: str,
                                        in_file: bool) -> None:
    if in_file:  # a mistake in the parameters file rather than on the command line
        key, value = param.split(":=")
        doc = yaml.safe_load(PARAMS.read_text())
        doc["/**"]["ros__parameters"][key] = value
        bad_file = tmp_path / "bad.yaml"
        bad_file.write_text(yaml.safe_dump(doc))
        node = NodeProcess("calibrator", ["--params-file", str(bad_file), "-r",
                                          "__node:=cal_bad"], tmp_path, name="cal_bad")
    else:
        node = calibrator(tmp_path, "cal_bad", "/bad/image", param)
    rc = node.wait(30)
    text = node.output()
    assert rc == 2, text
    assert f"parameter '{name}'" in text and "Traceback" not in text, text
    assert len([line for line in text.splitlines() if line.strip()]) == 1, text
