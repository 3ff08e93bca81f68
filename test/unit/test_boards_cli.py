"""Chessboard and ChArUco boards through the CLI and the live collection: artcal board at exact
scale, artcal synth -> detect --json -> calibrate round trips against truth, camera_calibration's
--size/--square, and the node's collector taking views from them."""

from __future__ import annotations

import json
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from artcal_ros import Board
from artcal_ros.cli.main import main
from artcal_ros.core.board.printable import board_to_png_px, layout_page, write_printable
from artcal_ros.core.detect import Detector
from artcal_ros.core.live.coverage import CoverageConfig, ViewCollector
from artcal_ros.core.live.stream import LiveDetection
from artcal_ros.synth import load_truth
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.dataset import write_dataset

CHESS_ARGS = ["--set", "board.type=chessboard", "--set", "board.cols=9", "--set",
              "board.rows=6", "--set", "board.square_length=0.04"]
CHARUCO_ARGS = ["--set", "board.type=charuco", "--set", "board.cols=7", "--set",
                "board.rows=5", "--set", "board.square_length=0.05", "--set",
                "board.marker_length=0.037"]


def test_charuco_print_is_opencvs_generate_image(tmp_path: Path) -> None:
    board = Board(board_type="charuco", cols=5, rows=4, legacy_pattern=True)
    dpi = 160 / 80 * 25.4        # 160 px per 80 mm square: whole pixels per module
    out = tmp_path / "charuco.png"
    layout = write_printable(board, out, dpi=dpi)
    page = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    x0, y0 = np.round(board_to_png_px(layout, np.array([[0.0, 0.0]]), dpi)[0] + 0.5).astype(int)
    crop = page[y0:y0 + 4 * 160, x0:x0 + 5 * 160]
    ref = board.to_cv_board().generateImage((5 * 160, 4 * 160), marginSize=0)
    assert np.mean((crop > 127) != (ref > 127)) < 1e-3


def test_chessboard_print_has_its_squares_where_the_board_says(tmp_path: Path) -> None:
    board = Board(board_type="chessboard", cols=8, rows=6, square_length=0.03)
    dpi = 254.0
    out = tmp_path / "chess.png"
    layout = write_printable(board, out, dpi=dpi)
    page = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    found, corners = cv2.findChessboardCorners(page, (8, 6))
    assert found
    corners = cv2.cornerSubPix(page, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 30, 0.01))
    want = board_to_png_px(layout, board.object_points(), dpi)
    d = np.linalg.norm(corners.reshape(-1, 1, 2) - want[None], axis=2).min(axis=1)
    assert d.max() < 0.3


@pytest.mark.parametrize(("kind", "args"), [("chessboard", CHESS_ARGS),
                                            ("charuco", CHARUCO_ARGS)])
def test_synth_detect_json_points_match_truth(tmp_path: Path, kind: str,
                                              args: list[str]) -> None:
    data = tmp_path / "data"
    assert main(["synth", *args, "--camera", "webcam", "--frames", "2", "--out", str(data),
                 "--partial-fraction", "0"]) == 0
    truth = load_truth(data / "truth.json")
    assert truth.board.board_type == kind
    out = tmp_path / "det.json"
    pngs = sorted(str(p) for p in data.glob("*.png"))
    assert main(["detect", *pngs, *args, "--json", str(out), "--quiet"]) == 0
    images = json.loads(out.read_text())["images"]
    for record, frame in zip(images, truth.frames, strict=True):
        pts = {p["id"]: p["xy"] for p in record["points"]}
        assert len(pts) >= 0.9 * frame.points_inside.sum()
        true = dict(zip(frame.point_ids.tolist(), frame.points_px.tolist(), strict=True))
        err = [np.hypot(*(np.array(xy) - true[i])) for i, xy in pts.items()]
        assert max(err) < 0.15
        assert (len(record["markers"]) > 0) == (kind == "charuco")


def _calibrate_renders(tmp_path: Path, board: Board, frames: int, seed: int,
                       options: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """``artcal calibrate`` of whole-board webcam renders with ``options``: the camera
    matrix written, and the true one (both (3, 3), px)."""
    truth = load_truth(write_dataset(board, Camera.preset("webcam"), tmp_path / "data",
                                     frames=frames, seed=seed, partial_fraction=0.0))
    out = tmp_path / "cam.yaml"
    pngs = sorted(str(p) for p in (tmp_path / "data").glob("*.png"))
    assert main(["calibrate", *pngs, *options, "--output", str(out), "--quiet"]) == 0
    K = np.array(yaml.safe_load(out.read_text())["camera_matrix"]["data"]).reshape(3, 3)
    return K, np.array(truth.camera.to_dict()["K"])


def test_camera_calibration_size_and_square_calibrate_a_chessboard(tmp_path: Path) -> None:
    board = Board(board_type="chessboard", cols=9, rows=6, square_length=0.04)
    K, K_true = _calibrate_renders(tmp_path, board, 8, 3, ["--size", "9x6", "--square", "0.04"])
    assert abs(K[0, 0] / K_true[0, 0] - 1) < 0.003
    assert abs(K[0, 2] - K_true[0, 2]) < 1.0


def test_size_contradicting_board_type_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["calibrate", "x.png", "--size", "8x6", "--square", "0.03", "--set",
                 "board.type=charuco", "--output", "/tmp/never.yaml", "--quiet"])
    assert code == 2
    assert "contradicts" in capsys.readouterr().err
    assert main(["calibrate", "x.png", "--size", "8by6", "--quiet"]) == 2
    assert main(["calibrate", "x.png", "--square", "0.1", "--quiet"]) == 2


@pytest.mark.parametrize("board", [
    Board(board_type="chessboard", cols=9, rows=6, square_length=0.04),
    Board(board_type="charuco", cols=7, rows=5, square_length=0.05, marker_length=0.037),
    Board(board_type="aprilgrid", cols=6, rows=6, marker_length=0.088,
          marker_separation=0.0264),
    Board(board_type="circles", cols=7, rows=5, square_length=0.04),
    Board(board_type="acircles", cols=4, rows=11, square_length=0.03)],
    ids=["chessboard", "charuco", "aprilgrid", "circles", "acircles"])
def test_live_collection_keeps_views_of_point_boards(tmp_path: Path, board: Board) -> None:
    cam = Camera.preset("webcam")
    truth_path = write_dataset(board, cam, tmp_path / "d", frames=4, seed=9,
                               partial_fraction=0.0)
    frames = [cv2.imread(str(tmp_path / "d" / f.file), cv2.IMREAD_GRAYSCALE)
              for f in load_truth(truth_path).frames if f.file]
    collector = ViewCollector(board, CoverageConfig(min_views=2))
    live = LiveDetection(board, Detector(board).detect, collector)
    try:
        for image in frames:
            live.offer(image)
            deadline = time.monotonic() + 20
            while live.counts().measured == 0 and time.monotonic() < deadline:
                time.sleep(0.02)
            time.sleep(0.25)   # the newest frame is re-measured at most every refresh_s
    finally:
        live.stop(5.0)
    views = collector.views
    assert len(views) >= 2
    # points on chessboard, ChArUco and circle grids, markers (tags) on an aprilgrid
    assert all(v.n_features >= 8 for v in views)
    assert all(len(v.point_ids) >= 8 for v in views) == board.has_points


@pytest.mark.parametrize("kind", ["circles", "acircles"])
def test_circle_grids_calibrate_through_the_cli(tmp_path: Path, kind: str) -> None:
    board = (Board(board_type="circles", cols=7, rows=5, square_length=0.04) if kind == "circles"
             else Board(board_type="acircles", cols=4, rows=11, square_length=0.03))
    report = tmp_path / "report"
    sets = [x for k, v in board.to_params().items() for x in ("--set", f"{k}={v}")]
    K, K_true = _calibrate_renders(tmp_path, board, 10, 5, [*sets, "--report", str(report)])
    assert abs(K[0, 0] / K_true[0, 0] - 1) < 0.005
    assert abs(K[0, 2] - K_true[0, 2]) < 1.5
    summary = json.loads((report / "summary.json").read_text())
    assert summary["reprojection_rms_px"] < 0.1


def test_a4_chessboard_is_turned_to_fit_and_the_command_says_so(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A 225 x 175 mm chessboard (8x6 inner corners of 25 mm) with its white margin fits A4
    only with its long side along the paper's: it is turned, said so, and printed where
    :func:`board_to_png_px` says."""
    out, dpi = tmp_path / "chess.png", 100.0
    assert main(["board", "--size", "8x6", "--square", "0.025", "--paper", "A4",
                 "--out", str(out), "--dpi", f"{dpi:g}"]) == 0
    said = capsys.readouterr().out
    assert "A4 portrait" in said and "board turned a quarter turn" in said
    assert "(225 x 175 mm)" in said
    assert "mm of white around it" in said
    img = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (round(297 * dpi / 25.4), round(210 * dpi / 25.4))
    board = Board(board_type="chessboard", cols=8, rows=6, square_length=0.025)
    layout = layout_page(board, paper="A4")
    assert layout.turned
    want = board_to_png_px(layout, board.object_points(), dpi)
    found = None
    for size in ((8, 6), (6, 8)):
        ok, corners = cv2.findChessboardCorners(img, size)
        if ok:
            found = cv2.cornerSubPix(img, corners, (5, 5), (-1, -1), (
                cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.001)).reshape(-1, 2)
            break
    assert found is not None and len(found) == len(want)
    gap = np.linalg.norm(want[:, None, :] - found[None, :, :], axis=2).min(axis=1)
    assert gap.max() < 0.5


def test_a_wide_board_goes_landscape_and_a_fitting_one_stays_as_it_is(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["board", "--size", "10x3", "--square", "0.02", "--paper", "A4",
                 "--out", str(tmp_path / "wide.svg")]) == 0
    said = capsys.readouterr().out
    assert "A4 landscape, page 297.0 x 210.0 mm" in said and "turned" not in said
    assert "narrowed" not in said
    assert main(["board", "--size", "4x3", "--square", "0.02", "--paper", "A4",
                 "--out", str(tmp_path / "small.svg")]) == 0
    said = capsys.readouterr().out
    assert "A4 portrait, page 210.0 x 297.0 mm" in said and "turned" not in said
    assert "(100 x 80 mm)" in said
