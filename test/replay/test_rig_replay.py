"""A stereo recording replayed into the rig calibrator: the real replay node at rate 1.0 plays
bags/stereo (two 640x480 bgr8 topics at 15 Hz, the right camera's stamps jittered by up to
5 ms, rendered by ``artcal synth --rig stereo --bag``) once; the calibrator with
``cameras: [left, right]`` then calibrates the rig on ``~/calibrate`` and publishes both
CameraInfos, checked against the rig the bag was rendered from."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest
from sensor_msgs.msg import CameraInfo
from std_srvs.srv import Trigger

from test.integration.qos import LATCHED
from test.integration.ros_harness import PARAMS, ROOT, NodeProcess, Probe, wait_until

pytestmark = pytest.mark.replay

STEREO_BAG = ROOT / "bags" / "stereo"
# how bags/stereo was made (and is made again when missing)
SYNTH_ARGS = ("--rig", "stereo", "--bag", "--frames", "45", "--rate", "15", "--jitter-ms", "5",
              "--encoding", "bgr8", "--motion", "smooth", "--photometry", "exact",
              "--seed", "25")
MIN_VIEWS = 8


def stereo_bag(scratch: Path) -> Path:
    """bags/stereo, or the same recording rendered into ``scratch`` when it is missing."""
    if (STEREO_BAG / "metadata.yaml").is_file():
        return STEREO_BAG
    import subprocess

    out = scratch / "stereo"
    subprocess.run([str(ROOT / ".venv" / "bin" / "artcal"), "synth", "--params", str(PARAMS),
                    *SYNTH_ARGS, "--out", str(out)], check=True, capture_output=True)
    return out


def test_stereo_bag_replayed_calibrates_the_rig(tmp_path: Path, probe: Probe) -> None:
    from artcal_ros.synth import Camera
    from artcal_ros.synth.rig import Rig

    bag = stereo_bag(tmp_path)
    t0 = time.monotonic()
    infos = {n: probe.collect(CameraInfo, f"/replay_rig/{n}/camera_info", LATCHED)
             for n in ("left", "right")}
    node = NodeProcess("calibrator", [
        "--params-file", str(PARAMS), "-r", "__node:=rig_replay", "-r", "__ns:=/replay_rig",
        "-p", "cameras:=[left,right]", "-p", f"min_views:={MIN_VIEWS}",
        "-p", f"output_file:={tmp_path / 'unused.yaml'}"], tmp_path, name="rig_replay")
    # At the recorded pace, round and round as a user keeps showing the board, until the
    # pass during which the calibration came out (until_topic).
    player = NodeProcess("replay", [
        "-p", f"bag:={bag}", "-p", "rate:=1.0", "-p", "loop:=true", "-p", "wait_timeout:=30.0",
        "-p", "until_topic:=/replay_rig/right/camera_info", "-r", "__ns:=/replay_rig",
        "-p", "remap:=['/left/image_raw:=/replay_rig/left/image',"
              "'/right/image_raw:=/replay_rig/right/image']"], tmp_path, name="player")
    answers: list[str] = []

    def calibrated() -> bool:
        answer = probe.call(Trigger, "/replay_rig/rig_replay/calibrate", timeout=60.0)
        answers.append(answer.message)
        return bool(answer.success)

    try:
        wait_until(calibrated, 75.0, "a successful ~/calibrate", period=2.0)
    except AssertionError as e:
        raise AssertionError(f"{e}; answers: {answers[-2:]}") from None
    took = time.monotonic() - t0
    outliers = re.search(r"(\d+) outlier points", answers[-1])
    assert outliers and int(outliers.group(1)) < 50, answers[-1]   # views of one instant each
    wait_until(lambda: infos["left"] and infos["right"], 20.0, "both camera_info messages")
    assert player.wait(30) == 0, player.output()   # it ends after the pass that calibrated
    rig = Rig.preset("stereo", Camera.preset("webcam"))
    right = infos["right"][-1]
    P = np.asarray(right.p).reshape(3, 4)
    baseline = -P[0, 3] / P[0, 0]       # camera_calibration's Tx = -fx' * baseline
    true_baseline = float(np.linalg.norm(rig.extrinsics("left", "right")[1]))
    assert abs(baseline / true_baseline - 1) < 0.01, (baseline, true_baseline, answers[-1])
    for name in ("left", "right"):
        K = np.asarray(infos[name][-1].k).reshape(3, 3)
        assert abs(K[0, 0] / rig.camera(name).K[0, 0] - 1) < 0.01, (name, K)
    assert node.running()
    assert "Traceback" not in node.output()
    played = re.search(r"played (\d+) messages", player.output())
    print(f"stereo replay: calibrated after {took:.1f} s ({len(answers)} calls; "
          f"{played.group(1) if played else '?'} messages played, 90 a pass); baseline "
          f"{baseline:.5f} m")
