"""A board that is not found is named with what was seen instead; a partial success says so
first; a refused set still writes its report; ``--accept-weak`` solves and states the
uncertainty; the summary starts with a verdict and speaks of the board's own features.

Real photos: OpenCV's stereo chessboard (9x6 inner corners, test/data/real/opencv-stereo-chess)
and the ArUco tutorial's four ChArUco photos (5x7 squares, DICT_6X6_250, one tilt).
"""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from artcal_ros.cli.main import main
from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.calibrate.diagnosis import charuco_ratio_finding, chessboard_finding
from artcal_ros.core.calibrate.verdict import verdict_of
from artcal_ros.core.errors import CalibrationError
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
from test.conftest import PARAMS_FILE, ROOT
from test.unit.test_calibrate import truth_detections

REAL = ROOT / "test" / "data" / "real"
CHESS = sorted(str(p) for p in (REAL / "opencv-stereo-chess").glob("left*.jpg"))
CHARUCO = [str(REAL / "opencv-aruco-tutorial" / f"img_0{k}.jpg") for k in range(4)]
CHARUCO_SETS = ["--set", "board.type=charuco", "--set", "board.cols=5", "--set", "board.rows=7",
                "--set", "board.square_length=0.04", "--set", "board.marker_length=0.02"]


def run(args: list[str], capsys: pytest.CaptureFixture) -> tuple[int, str, str]:
    code = main(["calibrate", *args, "--params", str(PARAMS_FILE), "--quiet"])
    out, err = capsys.readouterr()
    assert "Traceback" not in out + err
    return code, out, err


# --- a board that is not found ---------------------------------------------------------------
def test_squares_counted_instead_of_inner_corners_names_the_size_seen(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code, _, err = run([*CHESS[:6], "--size", "10x7", "--square", "0.025",
                        "--output", str(tmp_path / "c.yaml")], capsys)
    assert code == 1
    assert "is found in 0 of 6 images" in err
    assert "found a chessboard of 9x6 inner corners in 4 of 4 images checked" in err
    assert "use --size 9x6" in err
    assert "tilted" not in err  # the views are not the problem


def test_wrong_dictionary_names_the_dictionary_in_view(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture) -> None:
    code, _, err = run([*CHARUCO, *CHARUCO_SETS, "--set", "board.dictionary=DICT_4X4_50",
                        "--output", str(tmp_path / "c.yaml")], capsys)
    assert code == 1
    assert "is found in 0 of 4 images" in err
    assert "the camera sees DICT_6X6_" in err and "board.dictionary" in err
    assert "tilted" not in err


def test_a_wrong_marker_square_ratio_on_the_charuco_photos_is_measured(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code, _, err = run([*CHARUCO, *CHARUCO_SETS[:-1], "board.marker_length=0.03", "--set",
                        "board.dictionary=DICT_6X6_250", "--output", str(tmp_path / "c.yaml")],
                       capsys)
    assert code == 1 and "is found in 0 of 4 images" in err
    measured = re.search(r"the markers measure about ([0-9.]+) of the square side", err)
    assert measured is not None and abs(float(measured.group(1)) - 0.5) < 0.03
    assert "the configuration says 0.75" in err
    # the board's own markers are in view: no other dictionary is named from chance decodes
    assert "the camera sees" not in err and "tilted" not in err


def _render_charuco(board: Board, n: int, seed: int) -> list[np.ndarray]:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(seed)
    poses = random_poses(board, cam, n, rng, partial_fraction=0.0, max_distance=0.9)
    return [render_view(board, cam, r, t, photometry=Photometry.clean(), rng=rng).image
            for r, t in poses]


PRINTED_CHARUCO = Board(board_type="charuco", cols=7, rows=5, square_length=0.04,
                        marker_length=0.02, dictionary_name="DICT_6X6_250")


def test_a_charuco_marker_length_that_does_not_fit_the_squares_is_measured() -> None:
    images = _render_charuco(PRINTED_CHARUCO, 3, seed=5)
    found = charuco_ratio_finding(images, replace(PRINTED_CHARUCO, marker_length=0.032))
    measured = re.search(r"the markers measure about ([0-9.]+) of the square side", found)
    assert measured is not None and abs(float(measured.group(1)) - 0.5) < 0.03
    assert "the configuration says 0.80" in found and "set board.marker_length" in found
    assert charuco_ratio_finding(images, PRINTED_CHARUCO) == ""  # a fitting ratio: nothing


def test_a_charuco_board_of_other_squares_is_named_in_squares() -> None:
    images = _render_charuco(PRINTED_CHARUCO, 2, seed=6)
    found = chessboard_finding(images, replace(PRINTED_CHARUCO, cols=8, rows=6))
    assert "6x4 inner corners" in found and "board.cols 7 and board.rows 5" in found


def test_few_points_in_most_views_advise_the_board_parameters_not_tilt() -> None:
    cam, dets = truth_detections("webcam", 8, seed=4)
    few = [d.subset(np.arange(min(3, len(d)))) if k > 1 else d for k, d in enumerate(dets)]
    with pytest.raises(CalibrationError, match="not found in 6 of 8 images") as info:
        calibrate(few, Board(), image_size=cam.size)
    assert "tilted" not in str(info.value)


# --- partial success -------------------------------------------------------------------------
def test_a_size_found_in_under_half_of_the_images_is_said_first(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code, out, _ = run([*CHESS, "--size", "8x6", "--square", "0.025",
                        "--output", str(tmp_path / "c.yaml")], capsys)
    first = out.splitlines()[0]
    assert code == 0
    assert first.startswith("the board (chessboard of 8x6 inner corners) is found in only ")
    assert "found a chessboard of 9x6 inner corners" in first and "use --size 9x6" in first
    assert out.splitlines()[1].startswith("verdict: usable: limited by ")


# --- refused sets, --accept-weak -------------------------------------------------------------
def test_a_refused_set_still_writes_its_report(tmp_path: Path,
                                               capsys: pytest.CaptureFixture) -> None:
    report = tmp_path / "report"
    code, _, err = run([*CHARUCO, *CHARUCO_SETS, "--set", "board.dictionary=DICT_6X6_250",
                        "--output", str(tmp_path / "c.yaml"), "--report", str(report)], capsys)
    assert code == 1 and "same angle" in err and str(report) in err
    summary = json.loads((report / "summary.json").read_text())
    assert summary["success"] is False and "same angle" in summary["reason"]
    assert summary["views_used"] == [] and summary["model"] == "plumb_bob"
    assert {"tone_curve", "board_check", "warnings", "points"} <= set(summary)
    assert [im["points"] for im in summary["per_image"]] == [24, 24, 24, 24]
    dets = json.loads((report / "detections.json").read_text())["images"]
    assert [len(im["markers"]) for im in dets] == [17, 17, 17, 17]
    coverage = cv2.imread(str(report / "coverage.png"))
    assert coverage is not None and coverage.std() > 5
    assert not (tmp_path / "c.yaml").exists()


def test_accept_weak_solves_and_states_the_uncertainty_first(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    report = tmp_path / "report"
    code, out, _ = run([*CHARUCO, *CHARUCO_SETS, "--set", "board.dictionary=DICT_6X6_250",
                        "--output", str(tmp_path / "c.yaml"), "--report", str(report),
                        "--accept-weak"], capsys)
    first = out.splitlines()[0]
    assert code == 0 and (tmp_path / "c.yaml").exists()
    assert first.startswith("verdict: poor: solved only because --accept-weak was given")
    assert "same angle" in first and "projection uncertainty" in first and "known to" in first
    summary = json.loads((report / "summary.json").read_text())
    assert summary["success"] is True and summary["verdict"]["level"] == "poor"
    assert "same angle" in summary["weak_reason"]
    assert "board check:" not in out  # a ChArUco board's print is not measured


def test_accept_weak_is_in_the_help(capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        main(["calibrate", "--help"])
    assert "--accept-weak" in capsys.readouterr().out


# --- verdict and wording ---------------------------------------------------------------------
def test_a_good_chessboard_calibration_reads_good_in_the_board_s_terms(
        tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    code, out, _ = run([*CHESS, "--size", "9x6", "--square", "0.025",
                        "--output", str(tmp_path / "c.yaml")], capsys)
    assert code == 0
    assert out.splitlines()[0].startswith("verdict: good: reprojection RMS ")
    assert "13 of 13 views used" in out.splitlines()[0]
    assert "markers" not in out  # a chessboard has none
    assert "tone curve:" not in out and "board check:" not in out


def test_verdict_rates_the_figures_and_names_what_limits_it() -> None:
    cam, dets = truth_detections("webcam", 12, seed=11)
    good = calibrate(dets, Board(), image_size=cam.size)
    assert verdict_of(good).level == "good"
    assert verdict_of(good).text().startswith("verdict: good: reprojection RMS")
    assert good.summary(long=True).splitlines()[0] == verdict_of(good).text()
    # 0.8 px on a 640 x 480 image is 0.1 % of its diagonal: good; 5 px is 0.6 %: poor
    shaky = verdict_of(replace(good, projection_uncertainty_rms_px=5.0))
    assert shaky.level == "poor"
    assert shaky.reason.startswith("limited by projection uncertainty 5.000 px RMS")
    noisy = verdict_of(replace(good, reprojection_rms_px=0.7))
    assert noisy.level == "usable" and noisy.reason.startswith("limited by reprojection RMS")
    fx_3_percent = {**good.std_devs, "fx": 0.03 * good.camera_matrix[0, 0]}
    loose = verdict_of(replace(good, std_devs=fx_3_percent))
    assert loose.level == "usable" and "known to 3 % (1-sigma, worst: fx)" in loose.reason
