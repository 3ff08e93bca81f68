"""A rig's small pieces: pairing images by stamp, Kalibr's camchain layout and lens names,
the header stamp read from a recorded message's bytes."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import yaml

from artcal_ros.bag.header import header_stamp_ns
from artcal_ros.bag.reader import BagMessage
from artcal_ros.core.camchain import ChainCamera, camchain_yaml, kalibr_model
from artcal_ros.core.camera import CameraModel
from artcal_ros.core.errors import ParameterError
from artcal_ros.core.sync import pair_by_stamp

MS = 1_000_000


def test_pairs_within_the_tolerance_and_counts_the_rest() -> None:
    # 15 Hz, right up to 5 ms off, a right image dropped, a lone left image at the end
    left = [i * 66 * MS for i in range(6)] + [1000 * MS]
    right = [s + d * MS for s, d in zip(left[:6], (3, -4, 5, 0, -2, 1), strict=True)]
    del right[2]
    frames, unpaired = pair_by_stamp({"left": left, "right": right}, tolerance_ns=10 * MS)
    assert frames == [{"left": 0, "right": 0}, {"right": 1, "left": 1},
                      {"left": 3, "right": 2}, {"left": 4, "right": 3},
                      {"left": 5, "right": 4}]
    assert unpaired == {"left": 2, "right": 0}


def test_a_camera_coming_again_opens_the_next_frame() -> None:
    # a 100 Hz camera beside a 10 Hz one: each slow image pairs with one fast image only
    fast = [i * 10 * MS for i in range(20)]
    slow = [i * 100 * MS + 2 * MS for i in range(2)]
    frames, unpaired = pair_by_stamp({"fast": fast, "slow": slow}, tolerance_ns=5 * MS)
    assert frames == [{"fast": 0, "slow": 0}, {"fast": 10, "slow": 1}]
    assert unpaired == {"fast": 18, "slow": 0}


def test_three_cameras_and_partial_frames() -> None:
    frames, unpaired = pair_by_stamp({"a": [0, 100], "b": [1, 300], "c": [2, 101]},
                                     tolerance_ns=5)
    assert frames == [{"a": 0, "b": 0, "c": 0}, {"a": 1, "c": 1}]
    assert unpaired == {"a": 0, "b": 1, "c": 0}
    with pytest.raises(ParameterError):
        pair_by_stamp({"a": [0]}, tolerance_ns=-1)


def _camera(model: str, dist: list[float]) -> CameraModel:
    K = np.array([[600.0, 0, 320.5], [0, 601.0, 240.5], [0, 0, 1]])
    return CameraModel(model, K, np.array(dist), (640, 480))


def test_lens_models_in_kalibrs_names() -> None:
    assert kalibr_model(_camera("plumb_bob", [-0.3, 0.1, 0.001, -0.002, 0.0]))[:3] == (
        "pinhole", "radtan", [-0.3, 0.1, 0.001, -0.002])
    assert kalibr_model(_camera("equidistant", [0.04, -0.01, 0.003, -0.0004]))[:3] == (
        "pinhole", "equidistant", [0.04, -0.01, 0.003, -0.0004])
    model, dist_model, coeffs, warning = kalibr_model(
        _camera("plumb_bob", [-0.3, 0.1, 0.001, -0.002, 0.02]))
    assert model == "pinhole" and dist_model == "plumb_bob"
    assert len(coeffs) == 5 and "k3" in warning


def test_camchain_layout_reads_back() -> None:
    T = np.eye(4)
    T[:3, 3] = [-0.12, 0.001, 0.0005]
    chain = [ChainCamera("left", _camera("plumb_bob", [-0.3, 0.1, 0, 0, 0]), "/l", None, (1,)),
             ChainCamera("right", _camera("rational_polynomial", [0.1] * 8), "/r", T, (0,))]
    text, warnings = camchain_yaml(chain)
    doc = yaml.safe_load(text)
    assert list(doc) == ["cam0", "cam1"] and "T_cn_cnm1" not in doc["cam0"]
    assert doc["cam0"]["intrinsics"] == [600.0, 601.0, 320.5, 240.5]
    assert doc["cam0"]["resolution"] == [640, 480] and doc["cam0"]["rostopic"] == "/l"
    assert np.array_equal(np.array(doc["cam1"]["T_cn_cnm1"]), T)
    assert doc["cam1"]["cam_overlaps"] == [0]
    assert doc["cam1"]["distortion_model"] == "rational_polynomial"
    assert len(warnings) == 1 and "cam1 (right)" in warnings[0]


@pytest.mark.parametrize("order", ["<", ">"])
def test_header_stamp_from_the_cdr_bytes(order: str) -> None:
    kind = b"\x00\x01" if order == "<" else b"\x00\x00"
    data = kind + b"\x00\x00" + struct.pack(order + "iI", 1_700_000_123, 456_789) + b"\x00" * 8
    msg = BagMessage("/t", "sensor_msgs/msg/Image", 5, 5, data, lambda b: None)
    assert header_stamp_ns(msg) == 1_700_000_123_000_456_789
    unstamped = kind + b"\x00\x00" + b"\x00" * 16
    assert header_stamp_ns(BagMessage("/t", "x", 5, 5, unstamped, lambda b: None)) == 5


def test_the_cameras_parameter() -> None:
    from artcal_ros.core.params import load_params

    # ROS gives an empty list of a parameters file as no value at all
    assert load_params(None, {"cameras": None})["cameras"] == []
    assert load_params(None, {"cameras": ["left", "right"]})["cameras"] == ["left", "right"]
    for bad, said in ((["left"], "names one camera"), (["a", "a"], "twice"),
                      (["a b", "c"], "not a camera name"), ("left", "a list of names")):
        with pytest.raises(ParameterError, match="parameter 'cameras'.*" + said):
            load_params(None, {"cameras": bad})
