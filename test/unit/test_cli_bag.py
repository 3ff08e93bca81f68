"""``artcal calibrate --bag``: every frame of the recording is detected unless the user bounds
it (``--max-frames N``), with a progress bar, and the calibration is the true camera's."""

from __future__ import annotations

from pathlib import Path

import pytest

from artcal_ros.bag import BagReader
from artcal_ros.cli.main import main
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.camera_info import read_camera_info_yaml
from artcal_ros.synth.truth import load_truth
from test.conftest import PARAMS_FILE, SAMPLE_BAG


def _frames_in_sample() -> int:
    with BagReader(SAMPLE_BAG) as r:
        return sum(1 for _ in r.messages("/camera/image_raw"))


def test_without_a_budget_every_frame_is_detected_and_the_camera_is_the_true_one(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    total = _frames_in_sample()
    out_file = tmp_path / "camera.yaml"
    code = main(["calibrate", "--bag", str(SAMPLE_BAG), "--params", str(PARAMS_FILE),
                 "--output", str(out_file)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert f"views: {total} given" in out  # one view per frame of the recording
    assert f"] {total}/{total} " in err  # the progress bar reached the end
    truth = load_truth(SAMPLE_BAG / "truth.json")
    rms_px, _ = projection_difference(truth.camera, read_camera_info_yaml(out_file))
    assert rms_px < 0.05  # sub-twentieth of a pixel over the whole image


def test_max_frames_bounds_the_frames_detected(tmp_path: Path,
                                               capsys: pytest.CaptureFixture) -> None:
    code = main(["calibrate", "--bag", str(SAMPLE_BAG), "--params", str(PARAMS_FILE),
                 "--output", str(tmp_path / "camera.yaml"), "--max-frames", "12", "--quiet"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "views: 12 given" in out


def test_a_negative_jobs_count_is_refused_by_name(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture) -> None:
    code = main(["calibrate", "--bag", str(SAMPLE_BAG), "--params", str(PARAMS_FILE),
                 "--output", str(tmp_path / "camera.yaml"), "--jobs", "-1"])
    _out, err = capsys.readouterr()
    assert code == 2
    assert "--jobs -1" in err and "Traceback" not in err
