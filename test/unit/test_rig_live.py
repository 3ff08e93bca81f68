"""The live rig's pairing by stamp (StampPairer) against the bag's (pair_by_stamp)."""

from __future__ import annotations

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
