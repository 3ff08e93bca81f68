"""A print that is not the configured board is named: ids outside it, or another dictionary;
the configured board's own frames and frames without markers give no finding; searches are
at most one per period."""

from __future__ import annotations

import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.live.board_mismatch import BoardMismatch
from artcal_ros.synth import Camera, Photometry, random_poses, render_view

CONFIGURED = Board()  # 19 x 9, DICT_6X6_1000, ids 0..170
PREFIX = "markers seen, none from the configured board (ids 0..170, dictionary DICT_6X6_1000)"


def frame(board: Board, seed: int = 1) -> np.ndarray:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(seed)
    rvec, tvec = random_poses(board, cam, 1, rng)[0]
    return render_view(board, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng).image


@pytest.mark.parametrize(("printed", "named"), [
    (Board(first_id=300), "DICT_6X6_1000 ids 300.."),
    (Board(cols=8, rows=5, dictionary_name="DICT_4X4_50"), "DICT_4X4_50 markers (ids 0.."),
    (Board(dictionary_name="DICT_5X5_250"), "DICT_5X5_250 markers"),
])
def test_a_foreign_print_is_named(printed: Board, named: str) -> None:
    finding = BoardMismatch(CONFIGURED).search(frame(printed))
    assert finding.startswith(PREFIX), finding
    assert named in finding, finding


def test_the_board_itself_and_an_empty_frame_give_nothing() -> None:
    check = BoardMismatch(CONFIGURED)
    assert check.search(np.full((480, 640), 128, np.uint8)) == ""
    # A frame of the board in which detection found markers clears any finding.
    assert check.observe(frame(CONFIGURED), markers_found=40) == ""


def test_searches_are_rate_limited_and_cleared_by_board_markers() -> None:
    now = [0.0]
    check = BoardMismatch(CONFIGURED, period_s=3.0, clock=lambda: now[0])
    foreign = frame(Board(first_id=300))
    assert check.observe(foreign, 0).startswith(PREFIX)
    blank = np.zeros((480, 640), np.uint8)
    now[0] = 1.0
    assert check.observe(blank, 0).startswith(PREFIX), "no new search within the period"
    now[0] = 3.5
    assert check.observe(blank, 0) == "", "a search of a blank frame clears it"
    now[0] = 7.0
    assert check.observe(foreign, 0).startswith(PREFIX)
    assert check.observe(foreign, 12) == "" and check.finding == ""
