"""Chessboard and ChArUco boards: geometry against OpenCV's, parameters, detection against the
renderer's exact truth, and the baselines on the same frames."""

from __future__ import annotations

from functools import cache

import cv2
import numpy as np
import pytest

from artcal_ros import Board
from artcal_ros.core.detect import Detector
from artcal_ros.core.detect.chessboard import squares_alternate
from artcal_ros.core.errors import ParameterError
from artcal_ros.core.params import validate
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.photometry import Photometry
from artcal_ros.synth.poses import random_poses
from artcal_ros.synth.view import RenderedView, render_view

CHESS = Board(board_type="chessboard", cols=9, rows=6, square_length=0.04)
CHESS_EVEN = Board(board_type="chessboard", cols=8, rows=6, square_length=0.04)
CHARUCO = Board(board_type="charuco", cols=7, rows=5, square_length=0.05, marker_length=0.037)
# defocus, JPEG and uneven light, as the "realistic" renders
REALISTIC = Photometry(gradient=0.4, vignetting=0.3, defocus_px=1.5, jpeg_quality=85,
                       full_well=4000.0, read_noise=6.0)


@cache
def _views(board: Board, n: int, partial: float, seed: int,
           realistic: bool = False) -> tuple[RenderedView, ...]:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(seed)
    phot = REALISTIC if realistic else Photometry.clean()
    return tuple(render_view(board, cam, r, t, photometry=phot, rng=rng)
                 for r, t in random_poses(board, cam, n, rng, partial_fraction=partial))


# --- geometry ---------------------------------------------------------------------------
@pytest.mark.parametrize("legacy", [False, True])
@pytest.mark.parametrize("size", [(5, 7), (6, 4)])
def test_charuco_geometry_is_opencvs(size: tuple[int, int], legacy: bool) -> None:
    board = Board(board_type="charuco", cols=size[0], rows=size[1], legacy_pattern=legacy)
    cv_board = cv2.aruco.CharucoBoard(size, 0.08, 0.06, board.dictionary)
    cv_board.setLegacyPattern(legacy)
    np.testing.assert_array_equal(board.ids, cv_board.getIds().ravel())
    np.testing.assert_allclose(board.object_corners(), np.array(cv_board.getObjPoints()),
                               atol=1e-7)
    np.testing.assert_allclose(board.object_points(), cv_board.getChessboardCorners(),
                               atol=1e-7)
    # the print, pixel for pixel (15 px per module: OpenCV's raster has no rounding)
    px = 160
    img = cv_board.generateImage((size[0] * px, size[1] * px), marginSize=0)
    ys, xs = np.mgrid[0:size[1] * px, 0:size[0] * px]
    white = board.is_white((xs + 0.5) * 0.08 / px, (ys + 0.5) * 0.08 / px)
    assert np.array_equal(white, img > 127)


def test_chessboard_points_follow_camera_calibration() -> None:
    pts = CHESS.object_points()
    assert pts.shape == (54, 3)
    np.testing.assert_allclose(pts[:2], [[0, 0, 0], [0.04, 0, 0]])
    np.testing.assert_allclose(pts[9], [0, 0.04, 0])            # row-major, cols per row
    np.testing.assert_allclose(CHESS.extent_m, (-0.04, -0.04, 0.36, 0.24))
    assert not CHESS.is_white(np.array([-0.02]), np.array([-0.02]))[0]   # top-left black
    assert CHESS.is_white(np.array([0.02]), np.array([-0.02]))[0]
    assert len(CHESS.ids) == 0 and CHESS.has_points


# --- parameters -------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["marker_grid", "chessboard", "charuco", "aprilgrid",
                                  "circles", "acircles"])
def test_every_board_type_of_the_design_is_built(kind: str) -> None:
    values = {"board.type": kind, "board.cols": 6, "board.rows": 5}
    if kind == "aprilgrid":
        values.update({"board.dictionary": "tag36h11", "board.marker_separation": 0.018})
    validate(values)
    assert Board.from_params({**values, "board.marker_length": 0.06 if kind != "charuco"
                              else 0.05}).board_type == kind


@pytest.mark.parametrize(("values", "message"), [
    ({"board.type": "charuco", "board.marker_length": 0.08}, "smaller than board.square"),
    ({"board.type": "charuco", "board.polarity": "white"}, "use black"),
    ({"board.type": "chessboard", "board.rows": 1}, "at least 2"),
    ({"board.type": "checkerboard"}, "not a board type"),
    ({"board.square_length": 0}, "board.square_length"),
])
def test_bad_board_parameters_are_refused(values: dict[str, object], message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        validate(values)


def test_board_parameters_round_trip() -> None:
    params = validate({"board.type": "charuco", "board.cols": 6, "board.rows": 4,
                       "board.legacy_pattern": True})
    board = Board.from_params(params)
    assert board.legacy_pattern and board.chess is not None and board.chess.white_top_left
    assert Board.from_params(board.to_params()) == board


# --- detection against truth --------------------------------------------------------------
def _errors(view: RenderedView, ids: np.ndarray, pts: np.ndarray) -> np.ndarray:
    return np.linalg.norm(pts - view.points_px[ids], axis=1)


def test_chessboard_corners_against_truth_and_opencv() -> None:
    detector = Detector(CHESS)
    ours, opencv = [], []
    for view in _views(CHESS, 3, 0.0, 3):
        det = detector.detect(view.image)
        assert len(det.point_ids) == 54       # whole board: every corner, each id right
        err = _errors(view, det.point_ids, det.points_px)
        assert err.max() < 0.1
        ours.append(err)
        found, c = cv2.findChessboardCorners(view.image, (9, 6))
        assert found
        c = cv2.cornerSubPix(view.image, c, (5, 5), (-1, -1),
                             (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01))
        d = np.linalg.norm(c.reshape(-1, 1, 2) - view.points_px[None], axis=2).min(axis=1)
        opencv.append(d)
    rms = float(np.sqrt(np.mean(np.concatenate(ours) ** 2)))
    rms_cv = float(np.sqrt(np.mean(np.concatenate(opencv) ** 2)))
    assert rms <= 0.03
    assert rms <= 0.5 * rms_cv


def test_chessboard_realistic_renders_beat_half_of_cornersubpix() -> None:
    ours, opencv = [], []
    detector = Detector(CHESS)
    for view in _views(CHESS, 2, 0.0, 4, realistic=True):
        det = detector.detect(view.image)
        assert len(det.point_ids) >= 50
        ours.append(_errors(view, det.point_ids, det.points_px))
        found, c = cv2.findChessboardCorners(view.image, (9, 6))
        if found:
            c = cv2.cornerSubPix(view.image, c, (5, 5), (-1, -1),
                                 (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01))
            opencv.append(np.linalg.norm(c.reshape(-1, 1, 2) - view.points_px[None],
                                         axis=2).min(axis=1))
    assert opencv
    rms = float(np.sqrt(np.mean(np.concatenate(ours) ** 2)))
    assert rms <= 0.5 * float(np.sqrt(np.mean(np.concatenate(opencv) ** 2)))


def test_chessboard_with_squares_of_six_pixels_is_found_and_measured() -> None:
    board = Board(board_type="chessboard", cols=9, rows=6, square_length=0.01)
    cam = Camera.preset("webcam")
    rvec = np.array([0.45, 0.2, 0.3])
    R = cv2.Rodrigues(rvec)[0]
    tvec = np.array([0.0, 0.0, 0.95]) - R @ np.array([0.04, 0.025, 0.0])
    view = render_view(board, cam, rvec, tvec, photometry=Photometry.clean(),
                       rng=np.random.default_rng(12))
    spacing = np.linalg.norm(np.diff(view.points_px.reshape(6, 9, 2), axis=1), axis=2)
    assert view.points_inside.all() and np.median(spacing) < 6.5
    det = Detector(board).detect(view.image)
    assert len(det.point_ids) >= 50
    assert _errors(view, det.point_ids, det.points_px).max() < 0.15


def test_chessboard_that_opencvs_finders_miss_for_its_small_squares_is_found() -> None:
    board = Board(board_type="chessboard", cols=9, rows=6, square_length=0.01)
    cam = Camera.preset("webcam")
    rvec = np.array([0.5, 0.3, 0.2])
    R = cv2.Rodrigues(rvec)[0]
    tvec = np.array([0.05, -0.03, 1.3]) - R @ np.array([0.05, 0.035, 0.0])
    view = render_view(board, cam, rvec, tvec, photometry=Photometry.clean(),
                       rng=np.random.default_rng(12))
    spacing = np.linalg.norm(np.diff(view.points_px.reshape(6, 9, 2), axis=1), axis=2)
    assert view.points_inside.all() and np.median(spacing) < 4.8
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    # the case: none of OpenCV's grid finders reads this board
    assert not cv2.findChessboardCorners(view.image, (9, 6), flags=flags)[0]
    assert not cv2.findChessboardCornersSB(view.image, (9, 6))[0]
    det = Detector(board).detect(view.image)
    assert len(det.point_ids) == 54
    assert _errors(view, det.point_ids, det.points_px).max() < 0.15


def test_grid_over_other_squares_is_not_taken_for_a_chessboard() -> None:
    view = _views(CHESS, 1, 0.0, 4)[0]
    grid = view.points_px.reshape(6, 9, 2)
    assert squares_alternate(view.image, grid)
    # the same grid over marker boards: code cells, margins and clutter, not a chequerboard
    for other in _views(Board(), 4, 0.0, 9):
        assert not squares_alternate(other.image, grid)
    # a marker grid of small markers, whose code cells hold many X-corners
    small = Board(cols=12, rows=8, marker_length=0.015, marker_separation=0.005)
    detector = Detector(Board(board_type="chessboard", cols=9, rows=6, square_length=0.01))
    for marker_view in _views(small, 3, 0.0, 8):
        assert len(detector.detect(marker_view.image).point_ids) == 0


def test_partial_chessboards_give_no_points() -> None:
    detector = Detector(CHESS)
    partial = [v for v in _views(CHESS, 3, 1.0, 5) if not v.points_inside.all()]
    assert partial
    for view in partial:
        assert len(detector.detect(view.image).point_ids) == 0


def test_symmetric_chessboard_ids_are_exact_up_to_its_half_turn() -> None:
    detector = Detector(CHESS_EVEN)
    for view in _views(CHESS_EVEN, 2, 0.0, 6):
        det = detector.detect(view.image)
        assert len(det.point_ids) == 48
        direct = _errors(view, det.point_ids, det.points_px).max()
        turned = _errors(view, 47 - det.point_ids, det.points_px).max()
        assert min(direct, turned) < 0.1
        # corner 0 is the one nearer the image's top-left
        first, last = det.points_px[det.point_ids == 0][0], det.points_px[det.point_ids == 47][0]
        assert first.sum() < last.sum()


def test_charuco_corners_against_truth_and_charuco_detector() -> None:
    detector = Detector(CHARUCO)
    cv_detector = cv2.aruco.CharucoDetector(CHARUCO.to_cv_board())
    errs = []
    for view in _views(CHARUCO, 4, 0.5, 7):
        det = detector.detect(view.image)
        err = _errors(view, det.point_ids, det.points_px)
        assert len(err) and err.max() < 0.15      # no wrong id: each within 0.15 px
        errs.append(err)
        _, cv_ids, _, _ = cv_detector.detectBoard(view.image)
        assert len(det.point_ids) >= (0 if cv_ids is None else len(cv_ids))
        assert np.all(view.points_inside[det.point_ids])
    assert float(np.sqrt(np.mean(np.concatenate(errs) ** 2))) <= 0.03


def test_charuco_in_clutter_names_no_wrong_corner() -> None:
    detector = Detector(CHARUCO)
    for view in _views(CHARUCO, 2, 1.0, 8, realistic=True):
        det = detector.detect(view.image)
        assert np.all(_errors(view, det.point_ids, det.points_px) < 0.3)


def test_saddle_fit_refuses_windows_cut_by_the_image_edge() -> None:
    from artcal_ros.core.detect.saddle import fit_saddles

    # a pixel-integrated X-corner at (x0, 20.25) seen through a lens blur of 0.8 px, edges
    # along the image axes (positions on the 1/8 px grid the supersampling draws exactly)
    def render(x0: float) -> np.ndarray:
        sub = 8
        ys, xs = np.mgrid[0:40 * sub, 0:60 * sub]
        u, v = (xs + 0.5) / sub - 0.5 - x0, (ys + 0.5) / sub - 0.5 - 20.25
        img = cv2.GaussianBlur(np.where(u * v > 0, 0.05, 0.8), (0, 0), 0.8 * sub)
        return img.reshape(40, sub, 60, sub).mean(axis=(1, 3))

    axes = np.array([[[14.0, 0.0], [0.0, 14.0]]])
    inside = fit_saddles(render(30.375), np.array([[30.0, 20.0]]), axes, np.array([True]))
    assert inside.ok[0]
    np.testing.assert_allclose(inside.points_px[0], [30.375, 20.25], atol=0.002)
    edge = fit_saddles(render(3.375), np.array([[3.0, 20.0]]), axes, np.array([True]))
    assert not edge.ok[0]
