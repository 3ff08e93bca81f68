"""The board options users bring from their home tools (camera_calibration's ``--size`` and
``--square``, Kalibr's ``--target``) on every verb that takes a board: ``artcal board`` prints
the same board as the explicit ``board.*`` parameters, ``artcal detect`` finds its points at
their true positions, and a bad option is one line naming what was wrong."""

from __future__ import annotations

import json
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
