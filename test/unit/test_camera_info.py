"""camera_calibration_parsers YAML: round trip, atomic writes, real ROS files, the P matrix."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from artcal_ros.core.camera_info import (
    CameraInfoData,
    as_camera_info,
    projection_matrix,
    read_camera_info_yaml,
    write_camera_info_yaml,
)
from artcal_ros.core.errors import ArtcalError, CalibrationError
from artcal_ros.synth import Camera

DATA = Path(__file__).resolve().parents[1] / "data" / "camera_info"
KEYS = ["image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
        "distortion_coefficients", "rectification_matrix", "projection_matrix"]


def _calibration(preset: str = "webcam") -> CameraInfoData:
    cam = Camera.preset(preset)
    # Values that need all 17 significant digits to survive the round trip.
    K = cam.K + np.array([[1 / 3, 0, 1 / 7], [0, 2 / 9, 1 / 11], [0, 0, 0]])
    return CameraInfoData(cam.size, "cam", K, cam.model, cam.dist + 1e-7 / 3, np.eye(3),
                          projection_matrix(K, cam.dist, cam.model, cam.size))


@pytest.mark.parametrize("preset", ["webcam", "fisheye"])
def test_write_read_round_trip_is_exact(tmp_path: Path, preset: str) -> None:
    cal = _calibration(preset)
    path = write_camera_info_yaml(tmp_path / "sub" / "camera.yaml", cal, camera_name="front")
    doc = yaml.safe_load(path.read_text())
    assert list(doc) == KEYS
    assert doc["distortion_model"] == cal.distortion_model
    back = read_camera_info_yaml(path)
    assert back.camera_name == "front" and back.image_size == cal.image_size
    assert np.array_equal(back.camera_matrix, cal.camera_matrix)
    assert np.array_equal(back.dist_coeffs, cal.dist_coeffs)
    assert np.array_equal(back.rectification_matrix, np.eye(3))
    assert np.array_equal(back.projection_matrix, cal.projection_matrix)
    assert [p.name for p in path.parent.iterdir()] == ["camera.yaml"]  # no temp file left


def test_failed_result_never_overwrites_a_good_file(tmp_path: Path) -> None:
    path = tmp_path / "camera.yaml"
    write_camera_info_yaml(path, _calibration())
    good = path.read_text()
    bad = _calibration()
    bad.camera_matrix[0, 0] = np.nan
    with pytest.raises(CalibrationError, match="non-finite"):
        write_camera_info_yaml(path, bad)
    assert path.read_text() == good
    assert [p.name for p in tmp_path.iterdir()] == ["camera.yaml"]


def test_unwritable_target_is_an_error_and_leaves_no_temp_file(tmp_path: Path) -> None:
    target = tmp_path / "camera.yaml"
    target.mkdir()  # a directory where the file should go: the rename must fail
    with pytest.raises(ArtcalError, match="cannot write"):
        write_camera_info_yaml(target, _calibration())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["camera.yaml"]
    assert target.is_dir()


def test_reads_real_ros_files_and_matches_their_projection_matrix() -> None:
    mono = read_camera_info_yaml(DATA / "raspicam_node__camerav2_1280x960.yaml")
    assert mono.image_size == (1280, 960) and mono.distortion_model == "plumb_bob"
    assert mono.camera_matrix[0, 0] == pytest.approx(1006.126285753055)
    assert mono.dist_coeffs.shape == (5,)
    # ROS's camera_calibration wrote P with getOptimalNewCameraMatrix(alpha=0); ours agrees to
    # 0.1 % (OpenCV versions sample the image border differently).
    ours = projection_matrix(mono.camera_matrix, mono.dist_coeffs, "plumb_bob", mono.image_size)
    np.testing.assert_allclose(ours, mono.projection_matrix, rtol=1e-3, atol=1.0)

    small = read_camera_info_yaml(DATA / "turtlebot3_autorace__camerav2_320x240_30fps.yaml")
    ours = projection_matrix(small.camera_matrix, small.dist_coeffs, "plumb_bob",
                             small.image_size)
    np.testing.assert_allclose(ours, small.projection_matrix, rtol=5e-3, atol=0.5)


def test_reads_legacy_stereo_file() -> None:
    left = read_camera_info_yaml(DATA / "raspicam_node__left_stereo.yaml")
    assert left.distortion_model == "plumb_bob"  # from the legacy key camera_model
    assert left.camera_name == "left_camera_optical_frame"
    assert left.rectification_matrix[0, 2] == pytest.approx(0.10642835)
    assert left.projection_matrix.shape == (3, 4)
    assert np.linalg.det(left.rectification_matrix) == pytest.approx(1.0, abs=1e-4)


def test_missing_field_is_named(tmp_path: Path) -> None:
    text = (DATA / "raspicam_node__camerav2_1280x960.yaml").read_text()
    broken = tmp_path / "broken.yaml"
    broken.write_text(text.replace("camera_matrix:", "camera_matrixx:"))
    with pytest.raises(ArtcalError, match="camera_matrix"):
        read_camera_info_yaml(broken)


def test_plumb_bob_projection_keeps_only_valid_pixels() -> None:
    cam = Camera.preset("webcam")  # strong barrel distortion
    P = projection_matrix(cam.K, cam.dist, cam.model, cam.size)
    assert P[0, 0] < cam.K[0, 0] and P[1, 1] < cam.K[1, 1]  # zoomed in
    assert np.all(P[:, 3] == 0) and P[2, 2] == 1
    w, h = cam.size
    mx, my = cv2.initUndistortRectifyMap(cam.K, cam.dist, np.eye(3), P[:, :3], (w, h),
                                         cv2.CV_32FC1)
    # alpha = 0: every pixel of the rectified image comes from inside the camera image.
    assert mx.min() > -1.0 and mx.max() < w and my.min() > -1.0 and my.max() < h


def test_equidistant_projection_is_k() -> None:
    cam = Camera.preset("fisheye")
    P = projection_matrix(cam.K, cam.dist, cam.model, cam.size)
    assert np.array_equal(P[:, :3], cam.K) and np.all(P[:, 3] == 0)


def test_camera_info_message_carries_the_yaml_numbers(tmp_path: Path) -> None:
    # The message is built from the arrays, not by printing and parsing the YAML: every
    # number is the same double as in the file.
    from artcal_ros.ros import msgs

    cal = _calibration()
    info = msgs.camera_info(cal, msgs.header(msgs.Time(sec=3), "cam_optical"))
    back = read_camera_info_yaml(write_camera_info_yaml(tmp_path / "c.yaml", cal))
    assert info.width == 640 and info.height == 480 and info.distortion_model == "plumb_bob"
    assert info.header.frame_id == "cam_optical" and info.header.stamp.sec == 3
    assert list(info.k) == back.camera_matrix.ravel().tolist()
    assert list(info.d) == back.dist_coeffs.tolist()
    assert list(info.r) == back.rectification_matrix.ravel().tolist()
    assert list(info.p) == back.projection_matrix.ravel().tolist()


def test_camera_info_of_a_camera_model_round_trips(tmp_path: Path) -> None:
    cam = Camera.preset("fisheye")
    info = as_camera_info(cam, "front")
    assert info.camera_name == "front" and np.array_equal(info.rectification_matrix, np.eye(3))
    back = read_camera_info_yaml(write_camera_info_yaml(tmp_path / "f.yaml", cam)).camera
    assert back.model == "equidistant" and back.size == cam.size
    assert np.array_equal(back.K, cam.K) and np.array_equal(back.dist, cam.dist)
