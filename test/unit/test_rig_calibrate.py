"""calibrate_rig against exact truth: extrinsics, intrinsics, uncertainty, fisheye pairs, given
intrinsics, a trio chained through its middle camera, partial views, a camera cut off, images
of different instants refused (or one such frame left out)."""

from __future__ import annotations

import numpy as np
import pytest

from artcal_ros import calibrate_rig
from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.calibrate.rig_result import RigResult
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import CalibrationError, ParameterError
from artcal_ros.synth.rig import Rig
from test.unit.rig_synth import BOARD, make_rig, rotation_error_deg


def _solve(rig: Rig, dets: dict[str, list[Detections]], board: Board = BOARD,
           **kw: object) -> RigResult:
    return calibrate_rig(dets, board, image_sizes={n: rig.camera(n).size for n in rig.names},
                         **kw)  # type: ignore[arg-type]


def _check_pair(rig: Rig, res: RigResult, a: str, b: str, *, baseline_pct: float,
                rotation_deg: float) -> None:
    R_true, t_true = rig.extrinsics(a, b)
    R, t = res.extrinsics[a, b]
    base = float(np.linalg.norm(t_true))
    assert abs(np.linalg.norm(t) - base) / base * 100 < baseline_pct, (a, b, t, t_true)
    assert rotation_error_deg(R_true, R) < rotation_deg
    pair = res.pairs[a, b]
    # the reported 1-sigma describes the real error (within 5 sigma)
    assert abs(pair.baseline_m - base) < 5 * pair.baseline_std_m + 1e-7
    assert rotation_error_deg(R_true, R) < 5 * float(np.linalg.norm(pair.rotation_std_deg))
    assert np.all(pair.translation_std_m > 0) and np.all(pair.rotation_std_deg > 0)


@pytest.mark.parametrize("points", ["corners", "centers"])
def test_stereo_pair_to_the_truth(points: str) -> None:
    rig, dets = make_rig("stereo", "webcam", 20, seed=3)
    res = _solve(rig, dets, points=points)
    _check_pair(rig, res, "left", "right", baseline_pct=0.05, rotation_deg=0.01)
    for n in rig.names:
        rms, _ = projection_difference(rig.camera(n), res.cameras[n])
        # one centre per marker carries less than its four corners (as for one camera)
        assert rms < (0.05 if points == "corners" else 0.12), (n, rms)
        assert rms < 3 * res.cameras[n].projection_uncertainty_rms_px
        assert res.cameras[n].reprojection_std_px == pytest.approx(0.03, rel=0.35)
    # both directions are one transform
    R, t = res.extrinsics["left", "right"]
    R2, t2 = res.extrinsics["right", "left"]
    assert np.allclose(R2, R.T, atol=1e-12) and np.allclose(t2, -R.T @ t, atol=1e-12)
    assert res.names == ("left", "right") and res.reference == "left"
    assert res.warnings == ()   # the cameras agree: no verdict warning
    assert res.shared_frames["left", "right"] == res.pairs["left", "right"].shared_frames >= 15
    summary = res.to_summary_dict()
    assert summary["extrinsics"][0]["from"] == "left"
    assert summary["extrinsics"][0]["baseline_m"] == pytest.approx(0.12, rel=5e-4)
    assert summary["rectified_epipolar_rms_px"]["left-right"] < 0.1
    # the right camera's CameraInfo: rectification and camera_calibration's Tx
    info = res.camera_info("right")
    P = info.projection_matrix
    assert P[0, 3] == pytest.approx(-P[0, 0] * res.pairs["left", "right"].baseline_m,
                                    rel=1e-9)
    assert np.allclose(res.camera_info("left").projection_matrix[:, 3], 0.0)


def test_fisheye_pair() -> None:
    rig, dets = make_rig("stereo", "fisheye", 20, seed=4)
    res = _solve(rig, dets, model="equidistant")
    _check_pair(rig, res, "left", "right", baseline_pct=0.05, rotation_deg=0.01)
    for n in rig.names:
        rms, _ = projection_difference(rig.camera(n), res.cameras[n])
        assert rms < 0.1, (n, rms)
    rect = res.rectification["left", "right"]
    assert rect.model == "equidistant" and not rect.vertical
    assert rect.epipolar_rms_px < 0.1 and rect.epipolar_points > 1000


def test_fixed_intrinsics_solve_only_the_extrinsics() -> None:
    rig, dets = make_rig("stereo", "webcam", 12, seed=5)
    given = {n: (rig.camera(n).K, rig.camera(n).dist) for n in rig.names}
    res = _solve(rig, dets, fixed_intrinsics=given)
    assert res.fixed_intrinsics
    for n in rig.names:
        assert np.array_equal(res.cameras[n].camera_matrix, rig.camera(n).K)
        assert np.array_equal(res.cameras[n].dist_coeffs, rig.camera(n).dist)
        assert res.cameras[n].free == () and res.cameras[n].std_devs == {}
    _check_pair(rig, res, "left", "right", baseline_pct=0.05, rotation_deg=0.01)


def test_trio_chained_through_the_middle_camera() -> None:
    rig, dets = make_rig("trio", "webcam", 24, seed=6)
    res = _solve(rig, dets)
    # the outer cameras never measure the board in the same frame
    assert res.shared_frames["cam0", "cam2"] == 0
    assert res.shared_frames["cam0", "cam1"] >= 3 and res.shared_frames["cam1", "cam2"] >= 3
    for a, b in (("cam0", "cam1"), ("cam1", "cam2"), ("cam0", "cam2")):
        _check_pair(rig, res, a, b, baseline_pct=0.05, rotation_deg=0.03)
    assert set(res.rectification) == {("cam0", "cam1"), ("cam1", "cam2")}
    # a rig of three writes monocular CameraInfos
    assert np.allclose(res.camera_info("cam1").rectification_matrix, np.eye(3))


def test_partial_views_only() -> None:
    board = Board.from_params({})   # 19 x 9 markers, 1.5 m wide: close views hold part of it
    rig, dets = make_rig("stereo", "webcam", 20, seed=7, board=board, partial_fraction=1.0)
    whole = [k for k in range(20) if all(len(dets[n][k]) == len(board.ids) for n in rig.names)]
    assert whole == []
    res = _solve(rig, dets, board)
    _check_pair(rig, res, "left", "right", baseline_pct=0.05, rotation_deg=0.01)


def test_a_camera_cut_off_is_named() -> None:
    rig, dets = make_rig("trio", "webcam", 24, seed=6)
    # cam2 keeps only the frames cam1 does not see: it shares none with the others
    cut = {n: list(v) for n, v in dets.items()}
    cut["cam2"] = [d2 if len(d1) == 0 else Detections.empty(d2.image_size)
                   for d1, d2 in zip(dets["cam1"], dets["cam2"], strict=True)]
    with pytest.raises(CalibrationError) as e:
        _solve(rig, cut)
    msg = str(e.value)
    assert "cam2 is not connected" in msg
    assert "cam0-cam2 0" in msg and "cam1-cam2 0" in msg
    assert "hold the board where cam2 and cam1 both see part of it" in msg


def test_bad_input_is_named() -> None:
    rig, dets = make_rig("stereo", "webcam", 3, seed=8)
    sizes = {n: rig.camera(n).size for n in rig.names}
    with pytest.raises(CalibrationError, match=r"different numbers of frames \(left 3, right 2\)"):
        calibrate_rig({"left": dets["left"], "right": dets["right"][:2]}, BOARD,
                      image_sizes=sizes)
    with pytest.raises(ParameterError, match="two or more cameras"):
        calibrate_rig({"left": dets["left"]}, BOARD, image_sizes=sizes)
    with pytest.raises(ParameterError, match=r"image_sizes lacks camera\(s\) right"):
        calibrate_rig(dets, BOARD, image_sizes={"left": (640, 480)})
    with pytest.raises(ParameterError, match="camera right: camera model 'pinhole'"):
        calibrate_rig(dets, BOARD, image_sizes=sizes,
                      model={"left": "plumb_bob", "right": "pinhole"})


def test_outlier_corners_are_dropped() -> None:
    rig, dets = make_rig("stereo", "webcam", 14, seed=10)
    rng = np.random.default_rng(0)
    bad = {n: list(v) for n, v in dets.items()}
    moved = 0
    for n in rig.names:
        for k in (1, 5, 9):
            d = bad[n][k]
            corners = d.corners_px.copy()
            pick = rng.choice(len(d), size=3, replace=False)
            corners[pick, 0] += rng.choice([-1.0, 1.0], size=(3, 2)) * 4.0   # 4 px off
            moved += 3
            bad[n][k] = Detections(d.ids, corners, d.centers_px, d.image_size, source=d.source)
    res = _solve(rig, bad)
    assert res.points_dropped >= moved
    _check_pair(rig, res, "left", "right", baseline_pct=0.05, rotation_deg=0.01)
    text = res.summary()
    assert text.splitlines()[1].startswith("left -> right: baseline 0.1200")
    assert "rectified epipolar RMS" in text and text.count("plumb_bob") == 2


def test_images_of_different_instants_are_refused() -> None:
    rig, dets = make_rig("stereo", "webcam", 10, seed=3)
    # right's images moved on by one: every rig frame pairs two instants
    shifted = {"left": dets["left"][:-1], "right": dets["right"][1:]}
    with pytest.raises(CalibrationError) as e:
        _solve(rig, shifted)
    msg = str(e.value)
    rms = float(msg.split("left-right: reprojection RMS ")[1].split()[0])
    assert rms > 5.0, msg   # board poses 1-3 px apart between the frames
    assert "where each camera alone fits the same points to 0.04" in msg, msg
    assert "not show the board at the same instant" in msg and "sync_tolerance" in msg


def test_one_frame_of_different_instants_is_left_out() -> None:
    rig, dets = make_rig("stereo", "webcam", 20, seed=3)
    mixed = {n: list(v) for n, v in dets.items()}
    mixed["right"][5] = dets["right"][6]
    res = _solve(rig, mixed)
    _check_pair(rig, res, "left", "right", baseline_pct=0.05, rotation_deg=0.01)
    # frame 5 pairs two instants: one of its cameras is left out (the one off the pose of
    # the camera with more points), nothing else
    apart = [d for d in res.frames_dropped if "not simultaneous" in d.reason]
    assert [d.view_index for d in apart] == [5], res.frames_dropped
    out = apart[0].reason.split(":")[0]
    assert 5 not in res.cameras[out].views_used
    assert sum(5 in res.cameras[n].views_used for n in rig.names) == 1
    assert res.warnings == ()
