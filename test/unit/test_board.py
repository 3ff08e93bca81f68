"""Board geometry, ids, polarity and validation."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from artcal_ros import Board, BoardError, load_params
from artcal_ros.core.params import validate


def test_object_points_match_opencv_gridboard() -> None:
    board = Board(cols=5, rows=3, marker_length=0.04, marker_separation=0.01, first_id=7)
    ours = board.object_corners()
    theirs = np.array(board.to_cv_board().getObjPoints())
    np.testing.assert_allclose(ours, theirs, atol=1e-7)
    np.testing.assert_array_equal(board.ids, np.arange(7, 22))
    assert board.cell_of(7) == (0, 0)
    assert board.cell_of(13) == (1, 1)
    np.testing.assert_allclose(board.object_centers([7])[0], [0.02, 0.02, 0.0])


def test_defaults_from_params_file(params_file) -> None:
    board = Board.from_params(load_params(params_file))
    assert (board.cols, board.rows, board.first_id) == (19, 9, 0)
    assert board.dictionary_name == "DICT_6X6_1000"
    w, h = board.size_m
    assert w == pytest.approx(19 * 0.08 - 0.02)
    assert h == pytest.approx(9 * 0.08 - 0.02)


@pytest.mark.parametrize(
    ("kwargs", "name"),
    [
        ({"cols": 0}, "board.cols"),
        ({"rows": -2}, "board.rows"),
        ({"marker_length": 0.0}, "board.marker_length"),
        ({"first_id": 990}, "board.first_id"),
        ({"dictionary_name": "DICT_NOPE"}, "board.dictionary"),
        ({"polarity": "grey"}, "board.polarity"),
        ({"marker_separation": 0.005}, "board.marker_separation"),
        ({"marker_separation": 0.01, "polarity": "mixed"}, "board.marker_separation"),
    ],
)
def test_bad_boards_name_the_parameter(kwargs, name) -> None:
    with pytest.raises(BoardError, match=name):
        Board(**kwargs)


def test_bad_parameter_values_are_named() -> None:
    from artcal_ros import ParameterError

    with pytest.raises(ParameterError, match=r"board\.cols"):
        validate({"board.cols": "many"})
    with pytest.raises(ParameterError, match="points"):
        validate({"points": "edges"})
    with pytest.raises(ParameterError, match="bogus"):
        validate({"bogus": 1})


def test_is_white_draws_each_marker_as_its_dictionary_code() -> None:
    board = Board(cols=3, rows=2, polarity="mixed")
    m = board.module_length
    for marker_id in board.ids:
        row, col = board.cell_of(int(marker_id))
        # sample the centre of each module
        k = np.arange(8) + 0.5
        xs, ys = np.meshgrid(col * board.pitch + k * m, row * board.pitch + k * m)
        got = board.is_white(xs, ys)
        code = cv2.aruco.generateImageMarker(board.dictionary, int(marker_id), 8) > 127
        want = ~code if board.is_inverted(int(marker_id)) else code
        np.testing.assert_array_equal(got, want)
        # the quiet zone around a marker has the opposite colour of its border
        gap = board.is_white(np.array([col * board.pitch - 0.004]),
                             np.array([row * board.pitch + 0.03]))
        assert bool(gap[0]) != bool(want[0, 0])
    assert board.is_inverted(1) and not board.is_inverted(0) and not board.is_inverted(4)
