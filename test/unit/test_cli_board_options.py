"""The board options users bring from their home tools (camera_calibration's ``--size`` and
``--square``, Kalibr's ``--target``) on every verb that takes a board: ``artcal board`` prints
the same board as the explicit ``board.*`` parameters, ``artcal detect`` finds its points at
their true positions, and a bad option is one line naming what was wrong."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from artcal_ros import Board
from artcal_ros.cli.main import main
from artcal_ros.synth import load_truth
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.dataset import write_dataset

KALIBR_APRILGRID = ("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 7\ntagSize: 0.088\n"
                    "tagSpacing: 0.3\n")


def _svg(tmp_path: Path, name: str, args: list[str]) -> str:
    out = tmp_path / f"{name}.svg"
    assert main(["board", *args, "--out", str(out)]) == 0
    return out.read_text()


def test_board_from_a_kalibr_target_is_the_board_of_its_parameters(tmp_path: Path) -> None:
    target = tmp_path / "april.yaml"
    target.write_text(KALIBR_APRILGRID)
    from_target = _svg(tmp_path, "target", ["--target", str(target)])
    explicit = _svg(tmp_path, "explicit", [
        "--set", "board.type=aprilgrid", "--set", "board.cols=6", "--set", "board.rows=7",
        "--set", "board.marker_length=0.088", "--set", "board.marker_separation=0.0264"])
    assert from_target == explicit
    plain = _svg(tmp_path, "plain", [])
    assert from_target != plain


def test_board_from_camera_calibration_size_and_square(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    from_size = _svg(tmp_path, "size", ["--size", "8x6", "--square", "0.03"])
    out = capsys.readouterr().out
    explicit = _svg(tmp_path, "explicit", [
        "--set", "board.type=chessboard", "--set", "board.cols=8", "--set", "board.rows=6",
        "--set", "board.square_length=0.03"])
    assert from_size == explicit
    assert "chessboard" in out


def _detect_matches_truth(tmp_path: Path, board: Board, seed: int, options: list[str],
                          n_points: int) -> None:
    """Render two whole-board views, ``artcal detect`` them with the board given only by
    ``options``, and find every point within 0.15 px of its true image."""
    data = tmp_path / "data"
    truth = load_truth(write_dataset(board, Camera.preset("webcam"), data, frames=2,
                                     seed=seed, partial_fraction=0.0))
    out = tmp_path / "det.json"
    pngs = sorted(str(p) for p in data.glob("*.png"))
    assert main(["detect", *pngs, *options, "--json", str(out), "--quiet"]) == 0
    images = json.loads(out.read_text())["images"]
    for record, frame in zip(images, truth.frames, strict=True):
        true = dict(zip(frame.point_ids.tolist(), frame.points_px.tolist(), strict=True))
        assert len(record["points"]) == len(true) == n_points
        err = [np.hypot(*(np.array(p["xy"]) - true[p["id"]])) for p in record["points"]]
        assert max(err) < 0.15


def test_detect_with_size_and_square_finds_the_true_points(tmp_path: Path) -> None:
    _detect_matches_truth(tmp_path, Board(board_type="chessboard", cols=9, rows=6,
                                          square_length=0.04), 17,
                          ["--size", "9x6", "--square", "0.04"], 54)


def test_detect_with_a_kalibr_circlegrid_finds_the_true_centres(tmp_path: Path) -> None:
    target = tmp_path / "circles.yaml"
    target.write_text("target_type: 'circlegrid'\ntargetCols: 4\ntargetRows: 11\n"
                      "spacingMeters: 0.02\nasymmetricGrid: True\n")
    _detect_matches_truth(tmp_path, Board(board_type="acircles", cols=4, rows=11,
                                          square_length=0.02), 23,
                          ["--target", str(target)], 44)


@pytest.mark.parametrize("verb", ["board", "detect"])
def test_bad_board_options_are_one_line_naming_the_fault(tmp_path: Path, verb: str,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    rest = ["--out", str(tmp_path / "b.svg")] if verb == "board" else [
        "x.png", "--json", str(tmp_path / "d.json")]
    bad = tmp_path / "bad.yaml"
    bad.write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: -1\n"
                   "tagSpacing: 0.3\n")
    assert main([verb, *rest, "--target", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "tagSize" in err and "Traceback" not in err
    assert main([verb, *rest, "--size", "9by6"]) == 2
    assert "--size" in capsys.readouterr().err
    target = tmp_path / "ok.yaml"
    target.write_text(KALIBR_APRILGRID)
    assert main([verb, *rest, "--target", str(target), "--size", "9x6"]) == 2
    assert "give one" in capsys.readouterr().err


# -- camera_calibration's flags: --pattern, --size, --square, --charuco_marker_size, --aruco_dict


@pytest.mark.parametrize(("flags", "params"), [
    (["--pattern", "charuco", "--size", "5x7", "--square", "0.04", "--charuco_marker_size",
      "0.03", "--aruco_dict", "6x6_250"],
     ["board.type=charuco", "board.cols=5", "board.rows=7", "board.square_length=0.04",
      "board.marker_length=0.03", "board.dictionary=DICT_6X6_250"]),
    (["--pattern", "charuco", "--size", "5x7", "--square", "0.04", "--charuco_marker_size",
      "0.03", "--aruco_dict", "DICT_4X4_50"],
     ["board.type=charuco", "board.cols=5", "board.rows=7", "board.square_length=0.04",
      "board.marker_length=0.03", "board.dictionary=DICT_4X4_50"]),
    (["--pattern", "charuco", "--size", "5x7", "--square", "0.04", "--charuco_marker_size",
      "0.03", "--aruco_dict", "aruco_orig"],
     ["board.type=charuco", "board.cols=5", "board.rows=7", "board.square_length=0.04",
      "board.marker_length=0.03", "board.dictionary=DICT_ARUCO_ORIGINAL"]),
    (["--pattern", "acircles", "--size", "4x11", "--square", "0.02"],
     ["board.type=acircles", "board.cols=4", "board.rows=11", "board.square_length=0.02"]),
    (["--pattern", "chessboard", "--size", "9x6", "--square", "0.025"],
     ["board.type=chessboard", "board.cols=9", "board.rows=6", "board.square_length=0.025"]),
], ids=["charuco", "charuco-opencv-dict", "charuco-aruco-orig", "acircles", "chessboard"])
def test_camera_calibration_flags_give_the_board_of_their_parameters(
        tmp_path: Path, flags: list[str], params: list[str]) -> None:
    from_flags = _svg(tmp_path, "flags", flags)
    explicit = _svg(tmp_path, "explicit", [a for p in params for a in ("--set", p)])
    assert from_flags == explicit


def test_charuco_size_counts_squares_as_camera_calibration_does(tmp_path: Path) -> None:
    """camera_calibration's ``--pattern charuco --size 5x7`` is a CharucoBoard of 5 x 7
    squares: its ``(5 - 1) x (7 - 1)`` corners are found where the renderer put them."""
    _detect_matches_truth(tmp_path, Board(board_type="charuco", cols=5, rows=7,
                                          square_length=0.04, marker_length=0.03,
                                          dictionary_name="DICT_6X6_250"), 29,
                          ["--pattern", "charuco", "--size", "5x7", "--square", "0.04",
                           "--charuco_marker_size", "0.03", "--aruco_dict", "6x6_250"], 24)


@pytest.mark.parametrize(("flags", "says"), [
    (["--size", "8x6"], "--size 8x6 needs --square"),
    (["--pattern", "charuco", "--size", "5x7", "--square", "0.04"],
     "--pattern charuco needs --charuco_marker_size and --aruco_dict"),
    (["--pattern", "charuco", "--size", "5x7", "--square", "0.04", "--aruco_dict", "6x6_250"],
     "--pattern charuco needs --charuco_marker_size"),
    (["--size", "8x6", "--square", "0.03", "--aruco_dict", "6x6_250"],
     "--aruco_dict is for --pattern charuco"),
    (["--pattern", "charuco", "--size", "5x7", "--square", "0.04", "--charuco_marker_size",
      "0.03", "--aruco_dict", "6x6_251"], "--aruco_dict '6x6_251': not an ArUco dictionary"),
    (["--pattern", "circles"], "--pattern needs --size"),
    (["--square", "25"], "--square 25: 25 m? lengths are in metres (25 mm is 0.025"),
    (["--size", "8x6", "--square", "25"],
     "--square 25: 25 m? lengths are in metres (25 mm is 0.025"),
    (["--size", "8x6", "--square", "0.0004"], "--square 0.0004: 0.4 mm is too small"),
    (["--pattern", "charuco", "--size", "5x7", "--square", "0.04", "--charuco_marker_size",
      "30", "--aruco_dict", "6x6_250"], "--charuco_marker_size 30: 30 m? lengths are in metres"),
])
@pytest.mark.parametrize("verb", ["board", "detect", "calibrate"])
def test_camera_calibration_flags_refused_with_one_line_naming_the_fault(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], verb: str, flags: list[str],
        says: str) -> None:
    rest = {"board": ["--out", str(tmp_path / "b.svg")],
            "detect": ["x.png", "--json", str(tmp_path / "d.json")],
            "calibrate": ["x.png", "--output", str(tmp_path / "c.yaml"), "--quiet"]}[verb]
    assert main([verb, *rest, *flags]) == 2
    err = capsys.readouterr().err
    assert says in err, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize(("key", "value", "says"), [
    ("board.square_length", "25", "parameter 'board.square_length': 25 m? lengths are in "
                                  "metres (25 mm is 0.025"),
    ("board.marker_length", "60", "parameter 'board.marker_length': 60 m? lengths are in metres"),
    ("board.marker_length", "0.0005", "parameter 'board.marker_length': 0.5 mm is too small"),
])
def test_implausible_lengths_in_parameters_are_refused(tmp_path: Path, key: str, value: str,
                                                       says: str,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    board = ["--set", "board.type=charuco", "--set", "board.cols=5", "--set", "board.rows=7",
             "--set", "board.square_length=0.04", "--set", "board.marker_length=0.03"]
    assert main(["board", "--out", str(tmp_path / "b.svg"), *board,
                 "--set", f"{key}={value}"]) == 2
    assert says in capsys.readouterr().err
    params = tmp_path / "p.yaml"
    params.write_text(f"/**:\n  ros__parameters:\n    {key}: {value}\n")
    from artcal_ros.core.errors import ParameterError
    from artcal_ros.core.params import load_params
    with pytest.raises(ParameterError, match=re.escape(says.split(": ", 1)[1].split(" (")[0])):
        load_params(params, {"board.type": "charuco"} if key == "board.square_length" else {})


def test_default_and_example_boards_pass_the_length_check() -> None:
    from artcal_ros.core.params import load_params

    root = Path(__file__).resolve().parents[2] / "config"
    load_params(None)
    for f in [root / "calibrator.yaml", *sorted((root / "boards").glob("*.yaml"))]:
        load_params(f)
    # a marker grid does not use board.square_length: it is not checked there
    load_params(None, {"board.square_length": 25})
