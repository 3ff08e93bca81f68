"""Stereo rectification against exact truth: rows agree after rectifying, camera_calibration's
Tx convention, OpenCV's rotations, fisheye and vertical pairs, and a rig solve's epipolar
error on noise-free points."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from artcal_ros import calibrate_rig
from artcal_ros.core.calibrate.rectify import rectify_pair, rectifying_rotations
from artcal_ros.core.camera import CameraModel
from artcal_ros.synth import Camera
from artcal_ros.synth.rig import Rig
from test.unit.rig_synth import BOARD, make_rig


def _model(cam: Camera) -> CameraModel:
    return CameraModel(cam.model, cam.K, cam.dist, cam.size)


def _scene(first: CameraModel, second: CameraModel, R: np.ndarray, t: np.ndarray,
           seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact images in both cameras of random points in front of both, pixels."""
    rng = np.random.default_rng(seed)
    X = np.c_[rng.uniform(-0.6, 0.6, 4000), rng.uniform(-0.4, 0.4, 4000),
              rng.uniform(0.8, 3.0, 4000)]
    a = first.project(X)
    b = second.project(X @ R.T + t)
    w, h = first.size
    ok = np.all(np.isfinite(a) & np.isfinite(b), axis=1)
    for p in (a, b):
        ok &= (p[:, 0] >= 0) & (p[:, 0] <= w - 1) & (p[:, 1] >= 0) & (p[:, 1] <= h - 1)
    return a[ok], b[ok]


@pytest.mark.parametrize("preset", ["webcam", "wide", "fisheye"])
def test_rectified_rows_agree_and_tx_convention(preset: str) -> None:
    rig = Rig.preset("stereo", Camera.preset(preset))
    first, second = _model(rig.camera("left")), _model(rig.camera("right"))
    R, t = rig.extrinsics("left", "right")
    a, b = _scene(first, second, R, t, seed=1)
    assert len(a) > 1000
    rect = rectify_pair("left", "right", first, second, R, t, a, b)
    # the points inside both rectified images count (most of them)
    assert rect.epipolar_rms_px < 0.01 and 0.5 * len(a) < rect.epipolar_points <= len(a)
    assert not rect.vertical
    # one rectified camera matrix; the right camera's Tx = -fx' * baseline (camera_calibration)
    assert np.array_equal(rect.P1[:, :3], rect.P2[:, :3])
    assert np.array_equal(rect.P1[:, 3], np.zeros(3))
    assert rect.P2[0, 3] == pytest.approx(-rect.P2[0, 0] * 0.12, rel=1e-9)
    assert rect.P2[1, 3] == 0.0 and rect.P2[2, 3] == 0.0
    assert rect.baseline_m == pytest.approx(0.12, rel=1e-9)
    # both rectified frames are one frame: R2 R R1^T = I
    assert np.allclose(rect.R2 @ R @ rect.R1.T, np.eye(3), atol=1e-12)
    for Rk in (rect.R1, rect.R2):
        assert np.allclose(Rk @ Rk.T, np.eye(3), atol=1e-12) and np.linalg.det(Rk) > 0
    # points stay in front and land in a sensible image: about the lens's own scale
    assert 0.5 * first.K[0, 0] < rect.P1[0, 0] < 2.0 * first.K[0, 0]


def test_rotations_match_opencv() -> None:
    rig = Rig.preset("stereo", Camera.preset("webcam"))
    first, second = _model(rig.camera("left")), _model(rig.camera("right"))
    R, t = rig.extrinsics("left", "right")
    R1, R2, _ = rectifying_rotations(R, t)
    cR1, cR2, cP1, _, _, _, _ = cv2.stereoRectify(first.K, first.dist, second.K, second.dist,
                                                  first.size, R, t,
                                                  flags=cv2.CALIB_ZERO_DISPARITY, alpha=0)
    assert np.allclose(R1, cR1, atol=1e-12) and np.allclose(R2, cR2, atol=1e-12)
    rect = rectify_pair("left", "right", first, second, R, t, np.zeros((0, 2)),
                        np.zeros((0, 2)))
    # alpha 0: the same zoom as OpenCV's, to a fraction of a percent
    assert rect.P1[0, 0] == pytest.approx(cP1[0, 0], rel=5e-3)


def test_vertical_pair_and_second_camera_on_the_left() -> None:
    cam = _model(Camera.preset("webcam"))
    # the second camera 10 cm below the first: its columns agree, Ty = -fy' * baseline
    R = cv2.Rodrigues(np.array([0.003, -0.002, 0.001]))[0]
    centre = np.array([0.002, 0.10, 0.0])
    t = -R @ centre
    a, b = _scene(cam, cam, R, t, seed=2)
    rect = rectify_pair("top", "bottom", cam, cam, R, t, a, b)
    assert rect.vertical and rect.epipolar_rms_px < 0.01
    assert rect.P2[1, 3] == pytest.approx(-rect.P2[1, 1] * np.linalg.norm(t), rel=1e-9)
    assert rect.P2[0, 3] == 0.0
    # the second camera on the first's left: Tx positive
    t = -R @ np.array([-0.12, 0.001, 0.0])
    a, b = _scene(cam, cam, R, t, seed=3)
    rect = rectify_pair("a", "b", cam, cam, R, t, a, b)
    assert not rect.vertical and rect.epipolar_rms_px < 0.01
    assert rect.P2[0, 3] == pytest.approx(rect.P2[0, 0] * np.linalg.norm(t), rel=1e-9)


def test_rig_solve_on_noise_free_points_rectifies_exactly() -> None:
    rig, dets = make_rig("stereo", "webcam", 12, seed=9, noise_px=0.0)
    res = calibrate_rig(dets, BOARD, image_sizes={n: rig.camera(n).size for n in rig.names})
    rect = res.rectification["left", "right"]
    assert rect.epipolar_points > 1000
    assert rect.epipolar_rms_px < 0.01
    assert res.rectified_epipolar_rms_px["left", "right"] == rect.epipolar_rms_px
    assert rect.P2[0, 3] == pytest.approx(-rect.P2[0, 0] * res.baseline_m["left", "right"],
                                          rel=1e-9)
