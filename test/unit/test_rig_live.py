"""The live rig's pairing by stamp (StampPairer) against the bag's (pair_by_stamp)."""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import pytest

from artcal_ros.core.errors import ParameterError
from artcal_ros.core.live.rig_frames import StampPairer
from artcal_ros.core.sync import pair_by_stamp

MS = 1_000_000


def _arrivals(stamps: dict[str, list[int]], rng: np.random.Generator) -> list[tuple[str, int]]:
    """(camera, index) in an arrival order: each camera's images in order, cameras mixed
    as a network delivers them (each image late by up to 30 ms)."""
    events = [(s + int(rng.uniform(0, 30 * MS)), n, k) for n, seq in stamps.items()
              for k, s in enumerate(seq)]
    events.sort()
    seen = {n: 0 for n in stamps}
    out = []
    for _, n, _ in events:   # per camera, the order stays the stamps' order
        out.append((n, seen[n]))
        seen[n] += 1
    return out


def _live(stamps: dict[str, list[int]], tolerance_ns: int, seed: int
          ) -> tuple[list[dict[str, int]], dict[str, int]]:
    pairer: StampPairer[int] = StampPairer(tuple(stamps), tolerance_ns)
    frames = []
    for n, k in _arrivals(stamps, np.random.default_rng(seed)):
        frames += [f.items for f in pairer.add(n, stamps[n][k], k)]
    return frames, pairer.unpaired()


def test_jittered_stereo_pairs_as_the_bag_pairing_does() -> None:
    rng = np.random.default_rng(3)
    t = [round(i * 1e9 / 15) for i in range(60)]
    stamps = {"left": t, "right": [s + int(rng.uniform(-5, 5) * MS) for s in t]}
    del stamps["right"][17]   # a dropped image
    frames, unpaired = _live(stamps, 10 * MS, seed=1)
    expected, expected_unpaired = pair_by_stamp(stamps, tolerance_ns=10 * MS)
    assert len(frames) == 59
    assert frames == expected
    # the left image without its partner is still waiting: the pairer cannot know yet
    # whether the right one comes late; the bag pairing counts it unpaired
    assert expected_unpaired == {"left": 1, "right": 0}
    assert unpaired == {"left": 1, "right": 0}


def test_three_cameras_one_slow() -> None:
    t = [i * 100 * MS for i in range(30)]
    stamps = {"cam0": t, "cam1": [s + 2 * MS for s in t], "cam2": t[::3]}
    frames, _ = _live(stamps, 10 * MS, seed=2)
    expected, _ = pair_by_stamp(stamps, tolerance_ns=10 * MS)
    # the last two frames wait for cam2, whose next image would fall after them
    assert frames == expected[:-2]
    assert len(expected) == 30
    assert sum(len(f) == 3 for f in frames) == 10


def test_a_camera_that_stops_leaves_the_other_unpaired() -> None:
    pairer: StampPairer[str] = StampPairer(("left", "right"), 10 * MS, max_lag_ns=500 * MS)
    assert pairer.add("left", 0, "l0") == []
    assert [f.items for f in pairer.add("right", 4 * MS, "r0")] == [{"left": "l0",
                                                                      "right": "r0"}]
    for i in range(1, 10):
        assert pairer.add("left", i * 100 * MS, f"l{i}") == []
    # images more than max_lag behind the newest (0.1 to 0.3 s) are given up
    assert pairer.unpaired() == {"left": 3, "right": 0}
    assert pairer.paired == 1


def test_a_recording_played_again_starts_afresh() -> None:
    pairer: StampPairer[int] = StampPairer(("a", "b"), 10 * MS)
    for i in range(5):
        pairer.add("a", 10**9 + i * 100 * MS, i)
        pairer.add("b", 10**9 + i * 100 * MS + MS, i)
    frames = [f.items for i in range(3) for f in
              (pairer.add("a", i * 100 * MS, i) + pairer.add("b", i * 100 * MS + MS, i))]
    assert frames == [{"a": i, "b": i} for i in range(3)]
    assert pairer.paired == 8


def test_unknown_camera_is_refused() -> None:
    pairer: StampPairer[int] = StampPairer(("a", "b"), 0)
    with pytest.raises(ParameterError, match="'c' is not one of a, b"):
        pairer.add("c", 0, 0)


@pytest.mark.parametrize("rotvec", [(0.1, -0.2, 0.3), (3.1, 0.0, 0.05), (0.0, 3.0, -0.4),
                                    (0.2, 0.1, -3.1), (0.0, 0.0, 0.0)])
def test_quaternion_of_a_rotation(rotvec: tuple[float, float, float]) -> None:
    import cv2

    from artcal_ros.core.calibrate.rig_files import quaternion_xyzw

    v = np.asarray(rotvec)
    R = cv2.Rodrigues(v)[0]
    x, y, z, w = quaternion_xyzw(R)
    angle = np.linalg.norm(v)
    axis = v / angle if angle else np.zeros(3)
    expected = np.array([*(np.sin(angle / 2) * axis), np.cos(angle / 2)])
    assert np.allclose([x, y, z, w], expected, atol=1e-12)


def _frames(dets: dict[str, list[Any]], k: int, drop: tuple[str, ...] = ()) -> dict[str, Any]:
    return {n: (None if n in drop else d[k]) for n, d in dets.items()}


def test_rig_views_keep_new_rig_views_and_count_what_each_pair_shares() -> None:
    from artcal_ros.core.live.rig_views import RigViews, RigViewsConfig
    from test.unit.rig_synth import BOARD, make_rig

    rig, dets = make_rig("stereo", "webcam", 14, seed=251)
    views = RigViews(BOARD, rig.names, RigViewsConfig(min_views=6))
    both = [k for k in range(14) if all(len(dets[n][k]) >= 6 for n in rig.names)]
    kept = [views.add(_frames(dets, k)) for k in range(14)]
    # a rig view needs two cameras measuring the board: frames aimed at one camera alone
    # that leave the other with fewer than 6 markers are not rig views
    assert [k for k in range(14) if kept[k]] == both
    assert not views.add(_frames(dets, both[0])), "the same view again is nothing new"
    snap = views.snapshot()
    assert len(snap.views) == len(both) >= 6
    assert snap.shared == {("left", "right"): len(both)}
    assert snap.enough and snap.problem is None and snap.not_connected == ()
    for n in rig.names:
        assert snap.readiness[n].views == len(both)
        assert 0 < snap.readiness[n].coverage <= 1
    detections = snap.detections()
    assert [d is not None for d in detections["right"]] == [True] * len(both)
    assert views.reset() == len(both) and not views.snapshot().views


def test_rig_views_name_the_camera_that_shares_too_few_views() -> None:
    from artcal_ros.core.live.rig_views import RigViews, RigViewsConfig
    from test.unit.rig_synth import BOARD, make_rig

    rig, dets = make_rig("trio", "webcam", 24, seed=252)
    views = RigViews(BOARD, rig.names, RigViewsConfig(min_views=3))
    for k in range(24):   # cam2 is shown the board in one rig view only
        views.add(_frames(dets, k, drop=("cam2",) if k else ()))
    snap = views.snapshot()
    assert snap.not_connected == ("cam2",)
    assert snap.problem is not None and "cam2 is not connected" in snap.problem
    assert not snap.enough
    assert "cam2 is not connected" in snap.summary()
    assert snap.shared[("cam0", "cam1")] >= 3


def test_a_held_rig_view_is_settled_by_its_precise_detections() -> None:
    from artcal_ros.core.live.rig_views import RigViews
    from test.unit.rig_synth import BOARD, make_rig

    rig, dets = make_rig("stereo", "webcam", 6, seed=253)
    k = next(k for k in range(6) if all(len(dets[n][k]) >= 6 for n in rig.names))
    views = RigViews(BOARD, rig.names)
    ticket = views.hold(_frames(dets, k))
    assert ticket is not None and views.pending == 1
    assert views.hold(_frames(dets, k)) is None, "held views count for novelty"
    assert views.settle(ticket, _frames(dets, k)) and views.pending == 0
    assert len(views.snapshot().views) == 1


@pytest.fixture(scope="module")
def stereo_images() -> list[dict[str, np.ndarray]]:
    """Three rendered 640x480 stereo frames in which both cameras see the board."""
    from artcal_ros.synth import Camera
    from artcal_ros.synth.rig import Rig, rig_poses
    from artcal_ros.synth.view import render_view
    from test.unit.rig_synth import BOARD

    rig = Rig.preset("stereo", Camera.preset("webcam"))
    out = []
    for pose in rig_poses(BOARD, rig, 8, np.random.default_rng(254), partial_fraction=0.0):
        views = {n: render_view(BOARD, rig.camera(n), *rig.camera_pose(n, pose)) for n in
                 rig.names}
        if all(len(v.ids) > 20 for v in views.values()):
            out.append({n: v.image for n, v in views.items()})
    return out[:3]


def test_rig_stream_makes_rig_views_of_paired_images_only(
        stereo_images: list[dict[str, np.ndarray]]) -> None:
    from artcal_ros.core.detect import Detector
    from artcal_ros.core.live.rig_stream import UNPAIRED_AFTER_S, RigStream
    from artcal_ros.core.live.rig_views import RigViews
    from test.unit.rig_synth import BOARD

    names = ("left", "right")
    views = RigViews(BOARD, names)
    detectors = {n: Detector(BOARD) for n in names}
    stream = RigStream(BOARD, names, {n: d.detect for n, d in detectors.items()}, views,
                       10 * MS, refresh_s=0.0)
    try:
        # right 50 ms after left: never one rig frame. The newest images are measured (they
        # seed the trackers) but, of two instants, make no rig view.
        t = 10**9
        for frame in stereo_images[:2]:
            stream.offer("left", frame["left"], t)
            stream.offer("right", frame["right"], t + 50 * MS)
            t += 100 * MS
        time.sleep(UNPAIRED_AFTER_S)
        stream.offer("left", stereo_images[0]["left"], t)   # wakes the worker
        wait_for(lambda: min(stream.measured().values()) >= 1, "both cameras measured")
        assert stream.pairer.paired == 0 and views.snapshot().views == []
        # within the tolerance: rig frames, measured into rig views
        for k, frame in enumerate(stereo_images):
            for n in names:
                stream.offer(n, frame[n], 10**10 + k * 100 * MS + (3 * MS if n == "right" else 0))
            wait_for(lambda k=k: len(views.snapshot().views) >= k + 1, f"rig view {k + 1}")
        assert stream.pairer.paired == 3
    finally:
        assert not stream.stop(timeout=10.0), "the worker thread ended"


def wait_for(predicate: Any, what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.02)


def test_frame_transforms_place_each_camera_in_the_first_as_tf_does() -> None:
    import cv2

    from artcal_ros import calibrate_rig
    from artcal_ros.core.calibrate.rig_files import frame_transforms
    from test.unit.rig_synth import BOARD, make_rig

    rig, dets = make_rig("stereo", "webcam", 12, seed=255)
    res = calibrate_rig(dets, BOARD, image_sizes={n: rig.camera(n).size for n in rig.names})
    ids = {"left": "left_optical", "right": "right_optical"}
    [(parent, child, t, q)] = frame_transforms(res, ids)
    assert (parent, child) == ("left_optical", "right_optical")
    # T_left_right: its translation is the right camera's centre in left's frame, 0.12 m
    # along left's x axis (the stereo preset); its rotation maps right's axes into left's
    R_right_left, t_right_left = rig.extrinsics("left", "right")
    assert np.allclose(t, -R_right_left.T @ t_right_left, atol=1e-4)
    assert np.allclose(t, [0.12, 0.0, 0.0], atol=1e-3)
    x, y, z, w = q
    angle = 2 * np.arctan2(np.linalg.norm([x, y, z]), w)
    axis = np.array([x, y, z]) / np.linalg.norm([x, y, z])
    R = cv2.Rodrigues(angle * axis)[0]
    assert np.allclose(R, R_right_left.T, atol=1e-4)
    assert frame_transforms(res, {"left": "cam", "right": "cam"}) == []
