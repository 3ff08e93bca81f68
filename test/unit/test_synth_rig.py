"""The renderer's rigs: extrinsics as specified, every camera's truth exact and consistent."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from artcal_ros.cli.main import main
from artcal_ros.core.board import Board
from artcal_ros.core.detect import detect
from artcal_ros.core.errors import ParameterError
from artcal_ros.synth import Camera, load_truth
from artcal_ros.synth.poses import feature_visibility
from artcal_ros.synth.rig import Rig, compose, invert, rig_poses, trio_yaw_deg
from artcal_ros.synth.rig_dataset import write_rig_dataset
from artcal_ros.synth.rig_truth import load_rig_truth

BOARD = Board.from_params({"board.cols": 10, "board.rows": 7, "board.marker_length": 0.03,
                           "board.marker_separation": 0.01})
BIG_BOARD = Board.from_params({})   # the default 19 x 9 board, 1.5 m wide
WEBCAM = Camera.preset("webcam")


def _axis_angle_deg(R: np.ndarray) -> float:
    """Angle between two cameras' optical axes, degrees."""
    return float(np.degrees(np.arccos(np.clip(R[2, 2], -1.0, 1.0))))


def test_stereo_extrinsics_as_specified() -> None:
    rig = Rig.preset("stereo", WEBCAM)
    assert rig.names == ("left", "right")
    R, t = rig.extrinsics("left", "right")   # p_right = R p_left + t
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.norm(t) == pytest.approx(0.12, abs=1e-12)
    centre_right_in_left = -R.T @ t
    assert np.allclose(centre_right_in_left, [0.12, 0.0, 0.0], atol=1e-12)
    assert 0.2 < _axis_angle_deg(R) < 0.6
    # the other direction is the inverse
    R2, t2 = rig.extrinsics("right", "left")
    assert np.allclose(R2, R.T) and np.allclose(t2, -R.T @ t)
    # the right camera is a copy of the model, not the same lens
    assert rig.camera("right").model == WEBCAM.model
    assert not np.allclose(rig.camera("right").K, WEBCAM.K)


def test_trio_extrinsics_fan_out() -> None:
    rig = Rig.preset("trio", WEBCAM)
    assert rig.names == ("cam0", "cam1", "cam2")
    R01, t01 = rig.extrinsics("cam0", "cam1")
    R02, t02 = rig.extrinsics("cam0", "cam2")
    yaw = trio_yaw_deg(WEBCAM)
    assert 35.0 <= yaw < 40.0   # the webcam's half field (31 deg) + 5
    assert _axis_angle_deg(R01) == pytest.approx(yaw, abs=0.5)
    assert _axis_angle_deg(R02) == pytest.approx(2 * yaw, abs=1.0)
    assert np.linalg.norm(t01) == pytest.approx(0.15, abs=1e-3)
    # chaining cam0 -> cam1 -> cam2 gives cam0 -> cam2
    R12, t12 = rig.extrinsics("cam1", "cam2")
    assert np.allclose(R12 @ R01, R02, atol=1e-12)
    assert np.allclose(R12 @ t01 + t12, t02, atol=1e-12)


@pytest.mark.parametrize("preset", ["webcam", "fisheye"])
def test_trio_outer_cameras_never_share_a_frame(preset: str) -> None:
    """The outer cameras of the trio never both see the board: the rig chains through cam1
    (a fisheye trio too: its outer cameras turn further out)."""
    rig = Rig.preset("trio", Camera.preset(preset))
    poses = rig_poses(BIG_BOARD, rig, 24, np.random.default_rng(3))
    seen = np.array([[feature_visibility(BIG_BOARD, rig.camera(n),
                                         *rig.camera_pose(n, p))[0].sum() >= 4
                      for n in rig.names] for p in poses])
    assert not (seen[:, 0] & seen[:, 2]).any()
    assert (seen[:, 0] & seen[:, 1]).sum() >= 5
    assert (seen[:, 1] & seen[:, 2]).sum() >= 5


def test_stereo_frames_include_partial_views() -> None:
    rig = Rig.preset("stereo", WEBCAM)
    poses = rig_poses(BIG_BOARD, rig, 30, np.random.default_rng(1))
    inside = np.array([[feature_visibility(BIG_BOARD, rig.camera(n),
                                           *rig.camera_pose(n, p))[0].mean()
                        for n in rig.names] for p in poses])
    both_whole = (inside == 1.0).all(axis=1)
    assert 0 < both_whole.sum() < len(poses)
    assert ((inside > 0) & (inside < 1)).any(axis=1).sum() >= 5


def test_folder_truth_reprojects(tmp_path: Path) -> None:
    """Each camera's truth corners are the board projected through that camera's truth and
    the frame's pose chained with the rig's extrinsics (checked with OpenCV's projection);
    the image shows them there."""
    rig = Rig.preset("stereo", WEBCAM)
    path = write_rig_dataset(BOARD, rig, tmp_path / "st", frames=3, seed=5,
                             photometry="clean")
    truth = load_rig_truth(path)
    assert truth.names == ("left", "right") and truth.rig == "stereo"
    R, t = truth.extrinsics("left", "right")
    R0, t0 = rig.extrinsics("left", "right")
    assert np.allclose(R, R0, atol=1e-12) and np.allclose(t, t0, atol=1e-12)
    obj = BOARD.object_corners().reshape(-1, 3)
    for frame in truth.frames:
        R_first = cv2.Rodrigues(frame.rvec)[0]
        for name in truth.names:
            cam = truth.cameras[name]
            Rc, tc = truth.poses[name]
            rvec = cv2.Rodrigues(Rc @ R_first)[0]
            tvec = Rc @ frame.tvec + tc
            px, _ = cv2.projectPoints(obj, rvec, tvec, cam.K, cam.dist)
            px = px.reshape(-1, 4, 2)
            view = frame.views[name]
            assert view.file == frame.file
            k = view.inside
            assert k.sum() >= 8
            err = np.abs(px[np.searchsorted(BOARD.ids, view.ids)][k] - view.corners_px[k])
            assert err.max() < 1e-5
        # each camera's folder holds a single-camera truth of the same frames
    for name in truth.names:
        single = load_truth(tmp_path / "st" / name / "truth.json")
        assert np.allclose(single.camera.K, truth.cameras[name].K)
        assert [f.file for f in single.frames] == [f.file for f in truth.frames]
        assert (tmp_path / "st" / name / truth.frames[0].file).exists()
    # the right camera's image shows its own truth (its own lens and place)
    view = truth.frames[0].views["right"]
    image = cv2.imread(str(tmp_path / "st" / "right" / truth.frames[0].file),
                       cv2.IMREAD_GRAYSCALE)
    dets = detect(image, BOARD)
    true = dict(zip(view.ids.tolist(), view.corners_px, strict=True))
    errors = np.array([np.abs(c - true[i]).max() for i, c in zip(dets.ids, dets.corners_px,
                                                                 strict=True)])
    assert len(errors) >= 8 and np.median(errors) < 0.1


def test_bag_topics_and_jittered_stamps(tmp_path: Path) -> None:
    from artcal_ros.bag import BagReader

    rig = Rig.preset("stereo", WEBCAM)
    path = write_rig_dataset(BOARD, rig, tmp_path / "bag", frames=3, seed=2, bag=True,
                             rate_hz=15.0, jitter_ms=5.0)
    truth = load_rig_truth(path)
    assert truth.topics == {"left": "/left/image_raw", "right": "/right/image_raw"}
    with BagReader(tmp_path / "bag") as reader:
        assert set(reader.topics) == {"/left/image_raw", "/right/image_raw"}
        stamps: dict[str, list[int]] = {"/left/image_raw": [], "/right/image_raw": []}
        for m in reader.messages():
            msg = m.decode()
            assert msg.header.frame_id == m.topic.split("/")[1]
            stamps[m.topic].append(msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec)
    left, right = (np.array(stamps[t]) for t in ("/left/image_raw", "/right/image_raw"))
    assert len(left) == len(right) == 3
    assert np.all(np.abs(right - left) <= 5e6) and np.any(right != left)
    assert np.allclose(np.diff(left), 1e9 / 15, atol=1)
    assert [f.views["right"].stamp_ns for f in truth.frames] == right.tolist()


def test_pose_helpers_invert_and_compose() -> None:
    a = (np.array([0.1, -0.2, 0.3]), np.array([0.5, 0.1, 2.0]))
    rvec, tvec = compose(a, invert(a))
    assert np.allclose(rvec, 0, atol=1e-12) and np.allclose(tvec, 0, atol=1e-12)


def test_bad_rig_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(ParameterError, match="--rig"):
        Rig.preset("quad", WEBCAM)
    assert main(["synth", "--rig", "stereo", "--frames", "1", "--out", str(tmp_path / "x"),
                 "--jitter-ms", "5"]) == 2
    assert "--jitter-ms needs --bag" in capsys.readouterr().err
    assert main(["synth", "--rig", "stereo", "--frames", "1", "--out", str(tmp_path / "y"),
                 "--bag", "--jitter-ms", "80"]) == 2
    assert "--jitter-ms" in capsys.readouterr().err
