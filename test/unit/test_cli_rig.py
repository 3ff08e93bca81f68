"""``artcal calibrate --camera ...``: a stereo rig from image folders and from a bag, against the
renderer's truth; the output files in their formats (Kalibr's camchain.yaml, camera_calibration
YAML with the rectification, summary.json); usage errors exit 2, a camera that sees nothing
exits 1 naming it, images of different instants exit 1 saying so."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from artcal_ros.cli.main import main
from artcal_ros.core.camera_info import read_camera_info_yaml, write_camera_info_yaml
from artcal_ros.synth.rig_truth import RigTruth, load_rig_truth

PARAMS = str(Path(__file__).resolve().parents[2] / "config" / "calibrator.yaml")
FRAMES = 14


@pytest.fixture(scope="module")
def stereo(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, RigTruth]:
    """14 frames of the stereo rig (webcam copies) and their truth."""
    root = tmp_path_factory.mktemp("rig")
    assert main(["synth", "--params", PARAMS, "--camera", "webcam", "--frames", str(FRAMES),
                 "--out", str(root / "st"), "--rig", "stereo", "--seed", "7"]) == 0
    return root / "st", load_rig_truth(root / "st" / "truth.json")


@pytest.fixture(scope="module")
def calibrated(stereo: tuple[Path, RigTruth], tmp_path_factory: pytest.TempPathFactory
               ) -> tuple[Path, Path, str]:
    """The folders calibrated: (output dir, report dir, stdout)."""
    data, _ = stereo
    root = tmp_path_factory.mktemp("out")
    out, report = root / "calib", root / "report"
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = main(["calibrate", "--camera", f"left={data}/left/*.png",
                     "--camera", f"right={data}/right/*.png", "--params", PARAMS,
                     "--output-dir", str(out), "--report", str(report), "--quiet"])
    assert code == 0
    return out, report, buf.getvalue()


def _rotation_error_deg(R: np.ndarray, R_true: np.ndarray) -> float:
    c = (np.trace(R @ R_true.T) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def _check_transform(T: np.ndarray, truth: RigTruth) -> None:
    R_true, t_true = truth.extrinsics("left", "right")
    assert T.shape == (4, 4) and np.allclose(T[3], [0, 0, 0, 1])
    baseline = np.linalg.norm(T[:3, 3])
    assert abs(baseline / np.linalg.norm(t_true) - 1) < 1e-3      # within 0.1 %
    assert np.linalg.norm(T[:3, 3] - t_true) < 2e-4                # 0.2 mm
    assert _rotation_error_deg(T[:3, :3], R_true) < 0.02


def test_camchain_reads_back_as_kalibr_lays_it_out(calibrated: tuple[Path, Path, str],
                                                   stereo: tuple[Path, RigTruth]) -> None:
    out, _, _ = calibrated
    _, truth = stereo
    chain = yaml.safe_load((out / "camchain.yaml").read_text())
    assert list(chain) == ["cam0", "cam1"]
    assert "T_cn_cnm1" not in chain["cam0"]
    for key, name in (("cam0", "left"), ("cam1", "right")):
        cam = chain[key]
        assert cam["camera_model"] == "pinhole" and cam["distortion_model"] == "radtan"
        assert cam["resolution"] == [640, 480]
        assert cam["rostopic"] == f"/{name}/image_raw"
        assert len(cam["distortion_coeffs"]) == 4
        K = truth.cameras[name].K
        fu, fv, pu, pv = cam["intrinsics"]
        assert abs(fu / K[0, 0] - 1) < 1e-3 and abs(fv / K[1, 1] - 1) < 1e-3
        assert abs(pu - K[0, 2]) < 0.5 and abs(pv - K[1, 2]) < 0.5
        assert cam["cam_overlaps"] == [1 if key == "cam0" else 0]
    # T_cn_cnm1 of cam1 is T_cam1_cam0: a point in left's frame to right's
    _check_transform(np.array(chain["cam1"]["T_cn_cnm1"], np.float64), truth)


def test_camera_yamls_rectify_the_truth_onto_common_rows(
        calibrated: tuple[Path, Path, str], stereo: tuple[Path, RigTruth]) -> None:
    out, _, _ = calibrated
    _, truth = stereo
    left, right = (read_camera_info_yaml(out / f"{n}.yaml") for n in ("left", "right"))
    assert left.camera_name == "left" and right.camera_name == "right"
    P1, P2 = left.projection_matrix, right.projection_matrix
    assert P1[0, 3] == 0 and np.allclose(P1[:, :3], P2[:, :3])
    # camera_calibration's convention: the second camera's Tx = -fx' * baseline
    baseline = np.linalg.norm(truth.extrinsics("left", "right")[1])
    assert -P2[0, 3] / P2[0, 0] == pytest.approx(baseline, rel=1e-3)
    for R in (left.rectification_matrix, right.rectification_matrix):
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-9) and np.linalg.det(R) > 0
    # the same board corner lands on the same row in both rectified images
    rows = []
    for frame in truth.frames:
        a, b = frame.views["left"], frame.views["right"]
        both = np.intersect1d(a.ids[a.inside], b.ids[b.inside])
        pa = a.corners_px[np.searchsorted(a.ids, both)].reshape(-1, 1, 2)
        pb = b.corners_px[np.searchsorted(b.ids, both)].reshape(-1, 1, 2)
        ra = cv2.undistortPoints(pa, left.camera_matrix, left.dist_coeffs,
                                 R=left.rectification_matrix, P=P1).reshape(-1, 2)
        rb = cv2.undistortPoints(pb, right.camera_matrix, right.dist_coeffs,
                                 R=right.rectification_matrix, P=P2).reshape(-1, 2)
        rows.append(ra[:, 1] - rb[:, 1])
    diff = np.concatenate(rows)
    assert len(diff) > 500
    assert np.sqrt(np.mean(diff ** 2)) < 0.05


def test_summary_and_report(calibrated: tuple[Path, Path, str],
                            stereo: tuple[Path, RigTruth]) -> None:
    _, report, stdout = calibrated
    _, truth = stereo
    summary: dict[str, Any] = json.loads((report / "summary.json").read_text())
    assert summary["success"] is True and summary["camera_names"] == ["left", "right"]
    ex = summary["extrinsics"][0]
    assert ex["from"] == "left" and ex["to"] == "right"
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.array(ex["rotation"]), np.array(ex["translation"])
    _check_transform(T, truth)
    assert ex["baseline_m"] == pytest.approx(np.linalg.norm(ex["translation"]))
    std = ex["std_devs"]
    assert len(std["rotation_deg"]) == 3 and len(std["translation_m"]) == 3
    assert 0 < max(std["translation_m"]) < 1e-3
    epi = summary["rectified_epipolar_rms_px"]["left-right"]
    assert 0 < epi < 0.1
    for name in ("left", "right"):
        cam = summary["cameras"][name]
        for key in ("model", "points", "intrinsics", "std_devs", "dist_coeffs",
                    "reprojection_rms_px", "holdout_rms_px", "views_used", "warnings",
                    "tone_curve", "board_check"):
            assert key in cam, (name, key)
        assert cam["intrinsics"]["fx"] == pytest.approx(truth.cameras[name].K[0, 0], rel=1e-3)
        assert (report / name / "residuals.png").exists()
    page = cv2.imread(str(report / "pair_left_right.png"))
    assert page is not None and page.shape[1] >= 900
    assert "left -> right: baseline 0.12" in stdout and "rectified epipolar RMS" in stdout


def test_a_count_mismatch_names_both_counts(stereo: tuple[Path, RigTruth], tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    data, _ = stereo
    short = tmp_path / "right"
    shutil.copytree(data / "right", short)
    sorted(short.glob("*.png"))[-1].unlink()
    code = main(["calibrate", "--camera", f"left={data}/left/*.png",
                 "--camera", f"right={short}/*.png", "--output-dir", str(tmp_path / "o"),
                 "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert f"left {FRAMES}" in err and f"right {FRAMES - 1}" in err


def test_images_of_different_instants_fail_saying_why(stereo: tuple[Path, RigTruth],
                                                      tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    data, _ = stereo
    for cam, keep in (("left", slice(None, -1)), ("right", slice(1, None))):
        (tmp_path / cam).mkdir()
        for f in sorted((data / cam).glob("*.png"))[keep]:
            shutil.copy(f, tmp_path / cam / f.name)
    code = main(["calibrate", "--camera", f"left={tmp_path}/left/*.png",
                 "--camera", f"right={tmp_path}/right/*.png", "--params", PARAMS,
                 "--output-dir", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1 and "Traceback" not in err
    assert "left-right: reprojection RMS" in err
    assert "not show the board at the same instant" in err
    assert not (tmp_path / "o" / "camchain.yaml").exists()


def test_a_bag_with_two_topics_pairs_by_stamp(stereo: tuple[Path, RigTruth], tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """The same frames as a bag, right stamped 3 ms after left, one right message alone."""
    from artcal_ros.bag import BagWriter
    from artcal_ros.core.images import numpy_to_image

    data, truth = stereo
    start = 1_700_000_000_000_000_000
    with BagWriter(tmp_path / "bag", storage="directory") as w:
        for i, frame in enumerate(truth.frames[:10]):
            for name, delay in (("left", 0), ("right", 3_000_000)):
                image = cv2.imread(str(data / name / str(frame.file)), cv2.IMREAD_GRAYSCALE)
                stamp = start + i * 66_666_667 + delay
                w.write(f"/stereo/{name}/image_raw", "sensor_msgs/msg/Image", stamp,
                        numpy_to_image(image, "mono8", stamp, name))
        w.write("/stereo/right/image_raw", "sensor_msgs/msg/Image", start + 10**9,
                numpy_to_image(image, "mono8", start + 10**9, "right"))
    out = tmp_path / "calib"
    code = main(["calibrate", "--bag", str(tmp_path / "bag"),
                 "--camera", "left=/stereo/left/image_raw",
                 "--camera", "right=/stereo/right/image_raw", "--output-dir", str(out),
                 "--quiet"])
    stdout = capsys.readouterr().out
    assert code == 0
    assert "10 rig frames paired by stamp" in stdout and "right 1 of 11" in stdout
    chain = yaml.safe_load((out / "camchain.yaml").read_text())
    assert chain["cam1"]["rostopic"] == "/stereo/right/image_raw"
    _check_transform(np.array(chain["cam1"]["T_cn_cnm1"], np.float64), truth)


def test_fixed_intrinsics_are_kept(stereo: tuple[Path, RigTruth], tmp_path: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    data, truth = stereo
    given = {}
    for name in truth.names:
        given[name] = write_camera_info_yaml(tmp_path / f"{name}_in.yaml",
                                             truth.cameras[name], name)
    common = ["calibrate", "--camera", f"left={data}/left/*.png",
              "--camera", f"right={data}/right/*.png", "--output-dir", str(tmp_path / "o"),
              "--quiet"]
    assert main([*common, "--set", "calibrate.fix_intrinsics=true",
                 "--intrinsics", f"left={given['left']}"]) == 2
    assert "--intrinsics right=YAML" in capsys.readouterr().err
    assert main([*common, "--intrinsics", f"left={given['left']}"]) == 2
    assert "calibrate.fix_intrinsics=true" in capsys.readouterr().err
    assert main([*common, "--set", "calibrate.fix_intrinsics=true",
                 "--intrinsics", f"left={given['left']}",
                 "--intrinsics", f"right={given['right']}"]) == 0
    for name in truth.names:
        got = read_camera_info_yaml(tmp_path / "o" / f"{name}.yaml")
        assert np.array_equal(got.camera_matrix, truth.cameras[name].K)
        assert np.allclose(got.dist_coeffs[:5], truth.cameras[name].dist[:5], atol=0)
    chain = yaml.safe_load((tmp_path / "o" / "camchain.yaml").read_text())
    _check_transform(np.array(chain["cam1"]["T_cn_cnm1"], np.float64), truth)


def test_usage_errors_exit_2_with_one_line(stereo: tuple[Path, RigTruth], tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    data, _ = stereo
    left, right = f"left={data}/left/*.png", f"right={data}/right/*.png"
    cases = [
        (["--camera", left, "--output-dir", str(tmp_path)], "two or more --camera"),
        (["--camera", left, "--camera", right], "--output-dir"),
        (["--camera", left, "--camera", left.replace("left=", "right="), "--camera",
          "bad name=x", "--output-dir", str(tmp_path)], "not a camera name"),
        (["--camera", left, "--camera", "right", "--output-dir", str(tmp_path)], "NAME=VALUE"),
        (["--camera", f"left={data}/left", "--camera", right, "--output-dir", str(tmp_path)],
         f"give the image files in it, e.g. {data}/left/*.png"),
        (["--bag", str(tmp_path / "nobag"), "--camera", "left=/a", "--camera", "right=/b",
          "--output-dir", str(tmp_path)], "nobag"),
    ]
    for argv, said in cases:
        code = main(["calibrate", *argv, "--quiet"])
        err = capsys.readouterr().err
        assert code == 2, (argv, err)
        assert len(err.strip().splitlines()) == 1 and said in err, err


def test_a_camera_that_sees_nothing_fails_naming_it(stereo: tuple[Path, RigTruth],
                                                    tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    data, _ = stereo
    blank = tmp_path / "blank"
    blank.mkdir()
    for i in range(FRAMES):
        cv2.imwrite(str(blank / f"frame_{i:04d}.png"), np.full((480, 640), 90, np.uint8))
    code = main(["calibrate", "--camera", f"left={data}/left/*.png",
                 "--camera", f"right={data}/right/*.png", "--camera", f"wall={blank}/*.png",
                 "--output-dir", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 1
    assert "calibration failed" in err and "wall" in err
    assert not (tmp_path / "o" / "camchain.yaml").exists()
