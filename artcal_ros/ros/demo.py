"""``make demo``: replay the sample bag into the real calibrator node over DDS and calibrate.

Starts the calibrator and replay nodes as separate processes on a private DDS domain
(random ROS_DOMAIN_ID, localhost only), replays the bag at its recorded speed (again
from the start while views are still missing: a busy machine measures fewer of them in
one pass), watches /diagnostics until enough views are collected and every view offered
is measured, calls ``~/calibrate``, and prints the one-line summary, the published
CameraInfo and the calibration file's path.

Nothing is written outside ``--out`` (default: a new temporary directory): the calibration
file and the node logs go there, and the demo and its nodes run with ``ROS_HOME`` and
``ROS_LOG_DIR`` inside it, so the calibrator's saved session (``$ROS_HOME/artcal/camera/``)
and the ROS logs stay there too. A real camera's later run therefore finds no demo session to
resume.

    python -m artcal_ros.ros.demo [--bag bags/sample] [--params config/calibrator.yaml]
                                  [--out DIR]

Without ``--bag`` / ``--params`` it uses ``bags/sample`` and ``config/calibrator.yaml`` of the
current directory when they exist, else the installed copies (``<prefix>/share/artcal_ros/``,
from colcon or pip), else those of the source checkout an editable install runs from.
"""

from __future__ import annotations

import argparse
import os
import site
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from artcal_ros.core.errors import ArtcalError
from artcal_ros.ros.processes import NodeProcess, private_domain_env

PACKAGE = "artcal_ros"
SAMPLE_BAG = Path("bags") / "sample"
PARAMS_FILE = Path("config") / "calibrator.yaml"
IMAGE_TYPE = "sensor_msgs/msg/Image"


class DemoError(Exception):
    """A one-line reason the demo cannot start (a user mistake or a missing file)."""


def _installed_share_dirs() -> list[Path]:
    """Where an install put the package's data files (``<prefix>/share/artcal_ros``).

    The ament index answers for a sourced ROS 2 workspace; ament_index_python may be absent
    (it is not a dependency of the pip path), so the prefix is also derived from where the
    package itself is installed (``<prefix>/lib/pythonX.Y/site-packages/artcal_ros``, as colcon
    and pip lay it out) and from this interpreter's prefixes (``pip install`` into a venv or
    ``--user``).
    """
    dirs: list[Path] = []
    try:
        from ament_index_python.packages import get_package_share_directory

        dirs.append(Path(get_package_share_directory(PACKAGE)))
    except (ImportError, LookupError, OSError, ValueError):  # absent, unset, not indexed
        pass
    import artcal_ros

    package = Path(artcal_ros.__file__).resolve().parent
    prefixes: list[Path] = []
    if package.parent.name in ("site-packages", "dist-packages"):
        # <prefix>/lib/pythonX.Y/site-packages, or Debian's <prefix>/local/lib/... layout
        prefixes += list(package.parents)[3:5]
    prefixes += [Path(sys.prefix), Path(site.getuserbase())]
    dirs += [prefix / "share" / PACKAGE for prefix in prefixes]
    return [d for i, d in enumerate(dirs) if d.is_dir() and d not in dirs[:i]]


def _source_checkout() -> Path | None:
    """The source tree this package runs from (an editable install or a plain checkout): the
    package's parent directory if its package.xml names this package, else None."""
    import artcal_ros

    root = Path(artcal_ros.__file__).resolve().parents[1]
    try:
        name = ET.parse(root / "package.xml").getroot().findtext("name")
    except (OSError, ET.ParseError):
        return None
    return root if name == PACKAGE else None


def data_file(relative: Path, option: str) -> Path:
    """A data file of the package for a default option value.

    Args:
        relative: its path relative to the project root / the share directory, e.g.
            ``bags/sample``.
        option: the command-line option that sets it instead, for the message.

    Returns:
        the first that exists of: the current directory's, the installed copy under
        ``<prefix>/share/artcal_ros``, the source checkout's.

    Raises:
        DemoError: none exists; the message names what was looked for, where, and ``option``.
    """
    shares = _installed_share_dirs()
    checkout = _source_checkout()
    bases = [Path.cwd(), *shares, *([checkout] if checkout is not None else [])]
    for base in bases:
        if (base / relative).exists():
            return base / relative
    where = ", ".join(str(b) for b in bases)
    if not shares:
        where += " (and found no installed share/artcal_ros)"
    raise DemoError(f"no {relative} in {where}; pass {option} PATH")


def _bag_timing(bag: Path) -> tuple[str, int, float]:
    """(image topic, image count, recorded span in seconds) of a bag."""
    from artcal_ros.bag import BagReader

    with BagReader(bag) as reader:
        topics = [t for t, kind in sorted(reader.topics.items()) if kind == IMAGE_TYPE]
        if not topics:
            raise DemoError(f"--bag: {bag} has no {IMAGE_TYPE} topic")
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


def private_ros_home(out: Path) -> dict[str, str]:
    """The environment that keeps what ROS 2 processes save inside ``out``: ``ROS_HOME``
    (the calibrator's session directory, rcl's default log directory) and ``ROS_LOG_DIR``
    (set too: a user's own setting of it would otherwise win)."""
    home = out / "ros_home"
    # The report's plotting library keeps its font cache under MPLCONFIGDIR (else ~/.cache).
    return {"ROS_HOME": str(home), "ROS_LOG_DIR": str(home / "log"),
            "MPLCONFIGDIR": str(out / "matplotlib")}


# What the progress lines count, said once before them (the node's diagnostics keys).
LEGEND = ("demo: progress lines count frames seen (reached the calibrator), processed (markers "
          "tracked and the overlay drawn), measured (detected precisely: only these become "
          "views), views kept / needed before ~/calibrate is called, and the image coverage")


def run(bag: Path, params_file: Path, out: Path, timeout_s: float,
        rate: float = 1.0, loop: bool = True) -> int:
    """The demo; 0 when the calibration succeeded.

    Args:
        bag: the recording to replay (absolute: the nodes run in ``out``).
        params_file: the calibrator's ROS 2 parameters file (absolute).
        out: directory for camera.yaml, the node logs, ROS_HOME (ROS logs, the saved
            session); the nodes' working directory.
        timeout_s: seconds to wait for enough views.
        rate: replay speed (1.0: as recorded).
        loop: replay again and again until enough views are collected (False: once).
    """
    # Our own DDS domain on this machine only, and our own ROS_HOME, before any rclpy
    # context exists (rcl picks its log directory then); the node processes inherit both.
    os.environ.update(private_domain_env())
    os.environ.update(private_ros_home(out))
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import CameraInfo
    from std_srvs.srv import Trigger

    topic, frames, span = _bag_timing(bag)
    yaml_path = out / "camera.yaml"
    print(f"demo: {bag} has {frames} images on {topic} over {span:.1f} s; "
          f"replaying {'in a loop ' if loop else 'once '}at rate {rate:.2f} into the "
          "calibrator "
          f"(ROS_DOMAIN_ID={os.environ['ROS_DOMAIN_ID']}, parameters {params_file}, "
          f"logs, session and calibration in {out})", flush=True)
    print(LEGEND, flush=True)
    # Run in ``out`` with absolute paths: nothing depends on where the demo was started.
    calibrator = NodeProcess.python_module("artcal_ros.ros.calibrator", [
        "--ros-args", "--params-file", str(params_file), "-r", f"image:={topic}",
        "-p", f"output_file:={yaml_path}"], out / "calibrator.log", cwd=out)
    replay = NodeProcess.python_module("artcal_ros.ros.replay", [
        "--ros-args", "-p", f"bag:={bag}", "-p", f"rate:={rate:.3f}",
        "-p", f"loop:={str(loop).lower()}"],
        out / "replay.log", cwd=out)
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
        played_at: float | None = None
        first_frame_at: float | None = None
        while True:
            rclpy.spin_once(node, timeout_sec=0.2)
            values = _diagnostics(diagnostics)
            line = (f"  frames seen {values.get('frames seen')}, processed "
                    f"{values.get('frames processed')}, measured "
                    f"{values.get('frames measured')}, views {values.get('views')}/"
                    f"{values.get('views needed')}, coverage "
                    f"{float(values.get('coverage', 0)):.0%}") if values else ""
            if line and line != last:
                print(line, flush=True)
                last = line
            if played_at is None and not replay.running():
                if replay.proc.returncode != 0:
                    print(f"demo: the replay node failed:\n{replay.tail()}")
                    return 1
                played_at = time.monotonic()
            queued = values.get("frames queued") if values else None
            enough = bool(values) and int(values["views"]) >= int(values["views needed"])
            if first_frame_at is None and values and int(values.get("frames seen", 0)) > 0:
                first_frame_at = time.monotonic()
            # With a loop, the whole recording is offered at least once before the solve.
            one_pass = first_frame_at is not None \
                and time.monotonic() - first_frame_at > span / rate + 1.0
            if enough and queued == "0" and (played_at is not None or (loop and one_pass)):
                break
            # Diagnostics come once a second: two after the end of the recording with
            # nothing queued are its final count.
            if played_at is not None and not loop and queued == "0" \
                    and time.monotonic() - played_at > 2.5:
                print(f"demo: the recording gave {values['views']} views; "
                      f"{values['views needed']} are needed (play it again and again: "
                      "leave out --once)")
                return 1
            if not calibrator.running():
                print(f"demo: the calibrator node stopped:\n{calibrator.tail()}")
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
    """Entry point of ``python -m artcal_ros.ros.demo``; 0 on success, 1 when the calibration
    failed, 2 on bad usage or a missing file (one line on stderr)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0] if __doc__ else None)
    ap.add_argument("--bag", type=Path, default=None,
                    help=f"rosbag2 MCAP recording (default: {SAMPLE_BAG} here, else the "
                         "installed sample)")
    ap.add_argument("--params", type=Path, default=None,
                    help=f"the calibrator's ROS 2 parameters file (default: {PARAMS_FILE} "
                         "here, else the installed one)")
    ap.add_argument("--out", type=Path, default=None,
                    help="directory for camera.yaml, the logs and the saved session (default: "
                         "a new temp dir)")
    ap.add_argument("--rate", type=float, default=1.0,
                    help="replay speed (default 1.0: as recorded)")
    ap.add_argument("--once", action="store_true",
                    help="play the recording once (default: again from the start until "
                         "enough views are collected)")
    ap.add_argument("--timeout", type=float, default=120.0,
                    help="seconds to wait for enough views")
    args = ap.parse_args(argv)
    try:
        bag = args.bag if args.bag is not None else data_file(SAMPLE_BAG, "--bag")
        params = args.params if args.params is not None else data_file(PARAMS_FILE, "--params")
        if not bag.exists():
            raise DemoError(f"--bag: no bag at {bag} (make sample-bag renders one)")
        if not params.is_file():
            raise DemoError(f"--params: no parameters file at {params}")
        out = args.out or Path(tempfile.mkdtemp(prefix="artcal-demo-"))
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise DemoError(f"--out: cannot create directory {out}: {e.strerror}") from None
    except DemoError as e:
        print(f"demo: {e}", file=sys.stderr)
        return 2
    t0 = time.monotonic()
    try:
        status = run(bag.resolve(), params.resolve(), out.resolve(), args.timeout,
                     args.rate, not args.once)
    except (DemoError, ArtcalError) as e:  # e.g. an unreadable bag: its one-line reason
        print(f"demo: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("demo: interrupted", file=sys.stderr)
        return 130
    print(f"demo: {'done' if status == 0 else 'FAILED'} in {time.monotonic() - t0:.0f} s")
    return status


if __name__ == "__main__":
    sys.exit(main())
