"""What ``ros2 launch artcal_ros calibrate_from_bag.launch.py`` starts, as a user runs it.

launch is not on PyPI, so the test starts the same two nodes with the same names, parameters
and remappings as separate processes (the launch file's defaults: the sample bag at rate 1.0,
looped until the calibrator's ``/camera_info`` arrives), waits the README's 25 s as a user
would, calls ``/calibrator/calibrate`` once and expects success; then the replay must end by
itself at the end of the pass that carried the result.
"""

from __future__ import annotations

import ast
import time
from pathlib import Path

import pytest
from sensor_msgs.msg import CameraInfo
from std_srvs.srv import Trigger

from test.integration.frames import SAMPLE_BAG
from test.integration.qos import LATCHED
from test.integration.ros_harness import PARAMS, ROOT, NodeProcess, Probe, wait_until

pytestmark = pytest.mark.integration

LAUNCH_FILE = ROOT / "launch" / "calibrate_from_bag.launch.py"
USER_WAIT_S = 25.0  # the README: call ~/calibrate about 25 s after starting the launch
BAG_SECONDS = 6.0  # bags/sample: 60 frames at 10 Hz


def launch_defaults() -> dict[str, str]:
    """The launch file's argument defaults given as plain strings, and its until_topic (read
    from its source: launch itself cannot be imported here)."""
    tree = ast.parse(LAUNCH_FILE.read_text())
    found: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "DeclareLaunchArgument":
            name = node.args[0]
            default = next((k.value for k in node.keywords if k.arg == "default_value"), None)
            if isinstance(name, ast.Constant) and isinstance(default, ast.Constant):
                found[name.value] = default.value
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "CAMERA_INFO"
                                                for t in node.targets):
            assert isinstance(node.value, ast.Constant)
            found["until_topic"] = node.value.value
    return found


def test_the_launch_files_nodes_calibrate_25_s_after_start_and_the_loop_ends(
        tmp_path: Path, probe: Probe) -> None:
    defaults = launch_defaults()
    assert defaults == {"image_topic": "/camera/image_raw", "rate": "1.0", "loop": "true",
                        "until_topic": "/camera_info"}, defaults
    results = probe.collect(CameraInfo, defaults["until_topic"], LATCHED)
    t0 = time.monotonic()
    # Node(executable="calibrator", name="calibrator", parameters=[params_file],
    #      remappings=[("image", image_topic)])
    calibrator = NodeProcess("calibrator", [
        "--params-file", str(PARAMS), "-r", "__node:=calibrator",
        "-r", f"image:={defaults['image_topic']}"], tmp_path, name="calibrator")
    # Node(executable="replay", name="replay", parameters=[{bag, rate, loop, until_topic}])
    replay = NodeProcess("replay", [
        "-r", "__node:=replay", "-p", f"bag:={SAMPLE_BAG}", "-p", f"rate:={defaults['rate']}",
        "-p", f"loop:={defaults['loop']}",
        "-p", f"until_topic:={defaults['until_topic']}"], tmp_path, name="replay")
    # The user's wait is the scenario; what follows asserts on effects only.
    while time.monotonic() - t0 < USER_WAIT_S:
        assert calibrator.running(), calibrator.output()
        assert replay.running(), f"the replay ended before ~/calibrate:\n{replay.output()}"
        time.sleep(0.5)
    answer = probe.call(Trigger, "/calibrator/calibrate", timeout=120)
    assert answer.success, f"{answer.message}\n{calibrator.tail(30)}"
    wait_until(lambda: results, 30, "the result on /camera_info")
    # It stops at the end of the pass under way: one bag length, and time to be sure.
    assert replay.wait(BAG_SECONDS + 60) == 0, replay.output()
    text = replay.output()
    assert "a message came on /camera_info: stopping after" in text, text
    assert "Traceback" not in text + calibrator.output()
    assert calibrator.running(), "the calibrator keeps running after the replay ends"
