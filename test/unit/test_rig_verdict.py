"""The rig verdict's figures and thresholds (core/calibrate/rig_verdict.py), and the board pose
a fisheye cannot tell from its mirror through the optical centre."""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.calibrate.model import estimate_pose, project
from artcal_ros.core.calibrate.rig import _in_front
from artcal_ros.core.calibrate.rig_verdict import PairCheck, refusal, warnings_of
from artcal_ros.core.calibrate.views import view_points
from artcal_ros.core.camera import CameraModel
from test.unit.rig_synth import BOARD, make_rig


def _check(joint: float, own: float = 0.04, *, share: float = 0.0, baseline: float = 0.12,
           bound: float = 1.2) -> PairCheck:
    return PairCheck("left", "right", 10, joint, own, (own, own), (0.0, share), baseline,
                     bound, joint, {k: joint for k in range(10)})


def test_thresholds() -> None:
    good = _check(0.045)   # adds 0.02 px to 0.04: noise
    assert good.problems() == [] and good.warning() is None and not good.hopeless()
    assert refusal([good]) is None and warnings_of([good]) == []
    mild = _check(0.2)     # adds 0.196 px: more than noise, less than a broken rig
    assert mild.problems() == [] and "add 0.20 px" in str(mild.warning())
    broken = _check(12.7)
    assert broken.hopeless()
    reason = str(refusal([good, broken]))
    assert reason.startswith("the rig solve is refused: left-right: reprojection RMS 12.7 px "
                             "over 10 rig frames")
    assert "a good rig adds under 0.5 px" in reason and "sync_tolerance" in reason
    # noisier cameras are allowed more: 3x their own RMS
    assert _check(2.0, own=0.8).problems() == []
    assert "outliers" in _check(0.045, share=0.3).problems()[0]
    far = _check(0.045, baseline=10.4, bound=1.2).problems()
    assert far == ["baseline 10.4 m, longer than the cameras' distances to the board allow "
                   "(at most 1.2 m)"]


def test_a_board_pose_behind_a_fisheye_is_turned_in_front() -> None:
    rig, dets = make_rig("stereo", "fisheye", 3, seed=4, noise_px=0.0)
    cam = rig.camera("left")
    model = CameraModel("equidistant", cam.K, cam.dist, cam.size)
    v = view_points(dets["left"][0], BOARD, "corners", 0)
    r, t = estimate_pose(v, cam.K, cam.dist, "equidistant")
    R = cv2.Rodrigues(r)[0]
    mirrored = (cv2.Rodrigues(R @ np.diag([-1.0, -1.0, 1.0]))[0].ravel(), -t)
    # the mirror projects to the same image: the ambiguity the rig must resolve
    same = project(v.object_points, *mirrored, cam.K, cam.dist, "equidistant")
    assert np.abs(same - v.image_points).max() < 1e-6
    r2, t2 = _in_front(v, model, mirrored)
    assert np.allclose(t2, t, atol=1e-9) and np.allclose(r2, r, atol=1e-9)
    kept = _in_front(v, model, (r, t))
    assert kept[0] is r and kept[1] is t
    assert float(t2[2]) > 0.2   # the board in front of the camera
