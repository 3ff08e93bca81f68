"""``make demo``: replay the sample bag into the real calibrator node over DDS and calibrate.

Starts the calibrator and replay nodes as separate processes on a private DDS domain
(random ROS_DOMAIN_ID, localhost only), watches /diagnostics until enough views are
collected, calls ``~/calibrate``, and prints the one-line summary, the published
CameraInfo and the calibration file's path. Nothing is written outside ``--out``.

    python -m artcal_ros.ros.demo [--bag bags/sample] [--out DIR]
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import IO, Any

ROOT = Path(__file__).resolve().parents[2]
DEFAULT_BAG = ROOT / "bags" / "sample"
PARAMS = ROOT / "config" / "calibrator.yaml"
IMAGE_TYPE = "sensor_msgs/msg/Image"
DETECT_S = 0.7  # a generous detection time per frame on a small machine, seconds


class Child:
    """A node process in its own process group, logging to a file."""

    def __init__(self, name: str, args: list[str], log_path: Path) -> None:
        self.name = name
        self.log_path = log_path
        self._log: IO[bytes] = open(log_path, "wb")  # noqa: SIM115 - closed in stop()
        self.proc = subprocess.Popen([sys.executable, "-m", *args], cwd=ROOT,
                                     stdout=self._log, stderr=subprocess.STDOUT,
                                     start_new_session=True)

    def stop(self, timeout: float = 10.0) -> int:
        """SIGINT (rclpy can hang on SIGTERM), SIGKILL after ``timeout`` s; exit status."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGINT)
                self.proc.wait(timeout)
            except ProcessLookupError:
                pass
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()
        self._log.close()
        return int(self.proc.returncode or 0)

    def tail(self, lines: int = 15) -> str:
        self._log.flush()
        return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])


def _bag_timing(bag: Path) -> tuple[str, int, float]:
    """(image topic, image count, recorded span in seconds) of a bag."""
    from artcal_ros.bag import BagReader

    with BagReader(bag) as reader:
        topics = [t for t, kind in sorted(reader.topics.items()) if kind == IMAGE_TYPE]
        if not topics:
            raise SystemExit(f"demo: {bag} has no {IMAGE_TYPE} topic")
        stamps = [m.log_time_ns for m in reader.messages(topics[:1])]
    return topics[0], len(stamps), (stamps[-1] - stamps[0]) * 1e-9 if stamps else 0.0


def _diagnostics(msgs: list[Any]) -> dict[str, str]:
    for array in reversed(list(msgs)):
        for status in array.status:
            if status.name.startswith("calibrator:"):
                return {kv.key: kv.value for kv in status.values}
    return {}


def _compare_with_truth(bag: Path, yaml_path: Path) -> None:
    """Print how far the calibration is from the camera that rendered the bag, if known."""
    truth_path = bag / "truth.json" if bag.is_dir() else bag.with_name("truth.json")
    if not truth_path.is_file():
        return
    from artcal_ros.core.calibrate.quality import projection_difference
    from artcal_ros.core.camera_info import read_camera_info_yaml
    from artcal_ros.synth.truth import load_truth

    truth = load_truth(truth_path).camera
    rms, worst = projection_difference(truth, read_camera_info_yaml(yaml_path))
    print(f"demo: against the true camera in {truth_path.name}: projection difference "
          f"{rms:.3f} px RMS, {worst:.3f} px max over the image")


def run(bag: Path, out: Path, timeout_s: float, rate: float | None = None) -> int:
    """The demo; 0 when the calibration succeeded."""
    # Our own DDS domain on this machine only, before any rclpy context exists.
    os.environ["ROS_DOMAIN_ID"] = str(random.SystemRandom().randint(1, 200))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo
    from std_srvs.srv import Trigger

    topic, frames, span = _bag_timing(bag)
    period = span / max(1, frames - 1)
    if rate is None:
        rate = min(1.0, period / DETECT_S) if period > 0 else 1.0
    yaml_path = out / "camera.yaml"
    print(f"demo: {bag} has {frames} images on {topic} over {span:.1f} s; "
          f"replaying at rate {rate:.2f} into the calibrator "
          f"(ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, logs in {out})", flush=True)
    params = ["--params-file", str(PARAMS)] if PARAMS.is_file() else []
    calibrator = Child("calibrator", [
        "artcal_ros.ros.calibrator", "--ros-args", *params, "-r", f"image:={topic}",
        "-p", f"output_file:={yaml_path}"], out / "calibrator.log")
    replay = Child("replay", [
        "artcal_ros.ros.replay", "--ros-args", "-p", f"bag:={bag}", "-p", f"rate:={rate:.3f}",
        "-p", "loop:=true"], out / "replay.log")
    rclpy.init()
    node = rclpy.create_node("artcal_demo")
    diagnostics: list[Any] = []
    node.create_subscription(DiagnosticArray, "/diagnostics", diagnostics.append, 10)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    infos: list[Any] = []
    node.create_subscription(CameraInfo, "/camera_info", infos.append, latched)
    status = 1
    try:
        deadline = time.monotonic() + timeout_s
        last = ""
        while True:
            rclpy.spin_once(node, timeout_sec=0.2)
            values = _diagnostics(diagnostics)
            line = (f"  frames seen {values.get('frames seen')}, used {values.get('frames used')}"
                    f", views {values.get('views')}/{values.get('views needed')}, coverage "
                    f"{float(values.get('coverage', 0)):.0%}") if values else ""
            if line and line != last:
                print(line, flush=True)
                last = line
            if values and int(values["views"]) >= int(values["views needed"]):
                break
            for child in (calibrator, replay):
                if child.proc.poll() is not None:
                    print(f"demo: the {child.name} node stopped:\n{child.tail()}")
                    return 1
            if time.monotonic() > deadline:
                print(f"demo: not enough views after {timeout_s:g} s:\n{calibrator.tail()}")
                return 1
        replay.stop()
        print("demo: calling ~/calibrate ...", flush=True)
        client: Any = node.create_client(Trigger, "/calibrator/calibrate")
        if not client.wait_for_service(timeout_sec=20.0):
            print("demo: the calibrator's ~/calibrate service did not appear")
            return 1
        future = client.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(node, future, timeout_sec=120.0)
        answer = future.result()
        if answer is None:
            print(f"demo: ~/calibrate did not answer:\n{calibrator.tail()}")
            return 1
        print(f"demo: success={answer.success}: {answer.message}")
        if not answer.success:
            return 1
        t0 = time.monotonic()
        while not infos and time.monotonic() - t0 < 10.0:
            rclpy.spin_once(node, timeout_sec=0.2)
        if infos:
            k = infos[-1].k
            print(f"demo: camera_info ({infos[-1].distortion_model}): fx {k[0]:.2f} "
                  f"fy {k[4]:.2f} cx {k[2]:.2f} cy {k[5]:.2f}, d {list(infos[-1].d)}")
        print(f"demo: calibration written to {yaml_path}")
        _compare_with_truth(bag, yaml_path)
        status = 0
    finally:
        replay.stop()
        calibrator.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    return status


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m artcal_ros.ros.demo``."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--bag", type=Path, default=DEFAULT_BAG, help="rosbag2 MCAP recording")
    ap.add_argument("--out", type=Path, default=None,
                    help="directory for camera.yaml and the node logs (default: a new temp dir)")
    ap.add_argument("--rate", type=float, default=None,
                    help="replay speed (default: slow enough for detection to see most "
                         "frames); at 1.0 the node keeps the newest frame and drops the rest")
    ap.add_argument("--timeout", type=float, default=120.0,
                    help="seconds to wait for enough views")
    args = ap.parse_args(argv)
    if not args.bag.exists():
        print(f"demo: no bag at {args.bag} (make sample-bag renders one)", file=sys.stderr)
        return 2
    out = args.out or Path(tempfile.mkdtemp(prefix="artcal-demo-"))
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    try:
        status = run(args.bag.resolve(), out.resolve(), args.timeout, args.rate)
    except KeyboardInterrupt:
        print("demo: interrupted", file=sys.stderr)
        return 130
    print(f"demo: {'done' if status == 0 else 'FAILED'} in {time.monotonic() - t0:.0f} s")
    return status


if __name__ == "__main__":
    sys.exit(main())
