"""Kalibr's AprilGrid: the print and numbering against Kalibr's definitions, detection against
the renderer's exact truth, the CLI (detect --json points, calibrate --target) and a
calibration against the true camera."""

from __future__ import annotations

import json
from functools import cache
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from artcal_ros import Board
from artcal_ros.cli.main import main
from artcal_ros.core.board.kalibr_target import target_params
from artcal_ros.core.board.printable import board_to_png_px, write_printable
from artcal_ros.core.detect import Detector
from artcal_ros.core.errors import BoardError, ParameterError
from artcal_ros.core.params import validate
from artcal_ros.synth import load_truth
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.dataset import write_dataset
from artcal_ros.synth.photometry import Photometry
from artcal_ros.synth.poses import random_poses
from artcal_ros.synth.view import RenderedView, render_view

# EuRoC / TUM VI: tagCols 6, tagRows 6, tagSize 0.088, tagSpacing 0.3
APRIL = Board(board_type="aprilgrid", cols=6, rows=6, marker_length=0.088,
              marker_separation=0.0264)
SMALL = Board(board_type="aprilgrid", cols=3, rows=2, marker_length=0.05,
              marker_separation=0.05 * 0.25)
# tag36h11 codes of ids 0 and 1 as the AprilTag family publishes them
TAG36H11_0, TAG36H11_1 = 0xd5d628584, 0xd97f18b49
APRIL_ARGS = ["--set", "board.type=aprilgrid", "--set", "board.dictionary=tag36h11",
              "--set", "board.cols=6", "--set", "board.rows=6",
              "--set", "board.marker_length=0.088", "--set", "board.marker_separation=0.0264"]


@cache
def _views(n: int, partial: float, seed: int) -> tuple[RenderedView, ...]:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(seed)
    return tuple(render_view(APRIL, cam, r, t, photometry=Photometry.clean(), rng=rng)
                 for r, t in random_poses(APRIL, cam, n, rng, partial_fraction=partial))


# --- geometry and print -------------------------------------------------------------------
def test_points_follow_kalibrs_numbering() -> None:
    b = SMALL
    T, s = 0.05, 0.0125
    height = 2 * T + s
    pts = b.object_points()
    assert pts.shape == (4 * 6, 3)
    # Kalibr: point (r, c) of the 4 x 6 grid at x = (c//2)(T+s) + (c%2)T, y up likewise
    for pid in range(24):
        r, c = divmod(pid, 6)
        x = (c // 2) * (T + s) + (c % 2) * T
        y_up = (r // 2) * (T + s) + (r % 2) * T
        np.testing.assert_allclose(pts[pid], [x, height - y_up, 0.0], atol=1e-12)
    # tag 0 bottom-left, tag 3 (second row from the bottom) top-left in this y-down frame
    assert b.cell_of(0) == (1, 0) and b.cell_of(2) == (1, 2) and b.cell_of(3) == (0, 0)
    # Kalibr's corners of tag 0: points 0, 1, 7, 6 (BL, BR, TR, TL on the print)
    np.testing.assert_array_equal(b.marker_point_ids(np.array([0]))[0], [6, 7, 1, 0])
    # each marker's corners (TL TR BR BL) are the same board points as its point ids
    ids = b.ids
    np.testing.assert_allclose(b.object_points(b.marker_point_ids(ids).ravel()).reshape(-1, 4, 3),
                               b.object_corners(ids), atol=1e-12)
    np.testing.assert_allclose(b.object_corners(np.array([3]))[0, 0], [0, 0, 0], atol=1e-12)


@pytest.mark.parametrize(("tag_id", "code"), [(0, TAG36H11_0), (1, TAG36H11_1)])
def test_tags_print_as_kalibr_prints_them(tag_id: int, code: int) -> None:
    modules = APRIL.marker_modules(tag_id)          # True = white, row 0 at the top
    assert modules.shape == (10, 10)
    ring = np.ones((10, 10), bool)
    ring[2:8, 2:8] = False
    assert not modules[ring].any()                  # the 2-bit black border
    # the code read row-major from the top-left module, most significant bit first, 1 white
    want = np.array([(code >> (35 - k)) & 1 for k in range(36)], bool).reshape(6, 6)
    np.testing.assert_array_equal(modules[2:8, 2:8], want)


def test_gap_crossings_are_black_and_gaps_white() -> None:
    T, s = APRIL.marker_length, APRIL.marker_separation
    p = T + s
    cross = [(-s / 2, -s / 2), (T + s / 2, T + s / 2), (6 * p - s / 2, 6 * p - s / 2)]
    gap = [(T + s / 2, T / 2), (T / 2, -s / 2), (-s / 2, 3 * p + T / 2)]
    x, y = np.array(cross + gap).T
    np.testing.assert_array_equal(APRIL.is_white(x, y), [False] * 3 + [True] * 3)
    np.testing.assert_allclose(APRIL.extent_m, (-s, -s, 6 * p, 6 * p), atol=1e-12)


def test_printed_tags_sit_where_the_board_says(tmp_path: Path) -> None:
    dpi = 4.0 * 25.4   # 4 px per mm: 20 px per 5 mm module
    out = tmp_path / "april.png"
    layout = write_printable(SMALL, out, dpi=dpi)
    page = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    dets = Detector(SMALL).detect(page)
    np.testing.assert_array_equal(dets.ids, SMALL.ids)
    want = board_to_png_px(layout, SMALL.object_corners().reshape(-1, 3)[:, :2], dpi)
    err = np.linalg.norm(dets.corners_px.reshape(-1, 2) - want, axis=1)
    assert err.max() < 0.1


@pytest.mark.parametrize(("values", "message"), [
    ({"board.polarity": "white"}, "board.polarity"),
    ({"board.dictionary": "DICT_4X4_50"}, "tag36h11"),
    ({"board.first_id": 3}, "board.first_id"),
])
def test_bad_aprilgrid_parameters_are_refused(values: dict[str, object], message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        validate({"board.type": "aprilgrid", **values})
    kw = {"polarity": "polarity", "dictionary": "dictionary_name", "first_id": "first_id"}
    key, value = next(iter(values.items()))
    with pytest.raises(BoardError, match=message):
        Board(board_type="aprilgrid", **{kw[key.split(".")[1]]: value})  # type: ignore[arg-type]


# --- detection against truth ----------------------------------------------------------------
def _errors(views: tuple[RenderedView, ...]) -> tuple[np.ndarray, int, int, int]:
    """Corner errors (px) of the right ids, wrong ids, tags found, tags wholly visible."""
    detector = Detector(APRIL)
    errors: list[float] = []
    wrong = found = visible = 0
    for v in views:
        dets = detector.detect(v.image)
        at = {int(k): j for j, k in enumerate(v.ids)}
        for k, c in zip(dets.ids, dets.corners_px, strict=True):
            e = np.linalg.norm(c - v.corners_px[at[int(k)]], axis=1)
            if e.max() > 1.0:
                wrong += 1
            else:
                errors.extend(e.tolist())
        found += len(dets)
        visible += int(v.inside.sum())
    return np.array(errors), wrong, found, visible


def test_tag_corners_against_truth_on_clean_renders() -> None:
    errors, wrong, found, visible = _errors(_views(6, 0.0, 3))
    assert wrong == 0
    assert found >= 0.97 * visible
    assert np.sqrt(np.mean(errors ** 2)) <= 0.03


def test_partial_views_give_the_visible_tags_and_no_wrong_id() -> None:
    errors, wrong, found, visible = _errors(_views(6, 1.0, 11))
    assert wrong == 0
    # 78 of 87 measured: the edge fit still drops 4 steeply foreshortened tags of frame 0
    assert found >= 0.85 * visible
    assert np.sqrt(np.mean(errors ** 2)) <= 0.05


# --- CLI ------------------------------------------------------------------------------------
def test_detect_json_lists_kalibr_points(tmp_path: Path) -> None:
    data = tmp_path / "data"
    assert main(["synth", *APRIL_ARGS, "--camera", "webcam", "--frames", "2", "--out",
                 str(data), "--partial-fraction", "0"]) == 0
    truth = load_truth(data / "truth.json")
    assert truth.board == APRIL
    out = tmp_path / "det.json"
    pngs = sorted(str(p) for p in data.glob("*.png"))
    assert main(["detect", *pngs, *APRIL_ARGS, "--json", str(out), "--quiet"]) == 0
    for record, frame in zip(json.loads(out.read_text())["images"], truth.frames, strict=True):
        assert len(record["points"]) == 4 * len(record["markers"]) > 0
        ids = [p["id"] for p in record["points"]]
        assert ids == sorted(ids)
        at = {int(k): j for j, k in enumerate(frame.ids)}
        # Kalibr's point id -> (tag, corner): tag k's points BL, BR, TR, TL are our BL BR TR TL
        for m in record["markers"]:
            pid = APRIL.marker_point_ids(np.array([m["id"]]))[0]
            xy = {p["id"]: p["xy"] for p in record["points"]}
            np.testing.assert_allclose([xy[int(i)] for i in pid], m["corners"])
            np.testing.assert_allclose(m["corners"], frame.corners_px[at[m["id"]]], atol=0.1)


def test_calibrate_with_a_kalibr_target_file_against_the_true_camera(tmp_path: Path) -> None:
    cam = Camera.preset("webcam")
    truth = load_truth(write_dataset(APRIL, cam, tmp_path / "data", frames=12, seed=5))
    target = tmp_path / "april_6x6.yaml"
    target.write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\n"
                      "tagSpacing: 0.3\n")
    out = tmp_path / "cam.yaml"
    pngs = sorted(str(p) for p in (tmp_path / "data").glob("*.png"))
    assert main(["calibrate", *pngs, "--target", str(target), "--output", str(out),
                 "--quiet"]) == 0
    K = np.array(yaml.safe_load(out.read_text())["camera_matrix"]["data"]).reshape(3, 3)
    K_true = np.array(truth.camera.to_dict()["K"])
    assert abs(K[0, 0] / K_true[0, 0] - 1) < 0.001
    assert abs(K[1, 1] / K_true[1, 1] - 1) < 0.001
    assert np.hypot(K[0, 2] - K_true[0, 2], K[1, 2] - K_true[1, 2]) < 0.5


# --- Kalibr target files ----------------------------------------------------------------------
def test_kalibr_targets_translate_into_board_parameters(tmp_path: Path) -> None:
    f = tmp_path / "t.yaml"
    f.write_text("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 7\ntagSize: 0.088\n"
                 "tagSpacing: 0.3\n")
    p = target_params(f)
    assert Board.from_params(p) == Board(board_type="aprilgrid", cols=6, rows=7,
                                         marker_length=0.088, marker_separation=0.0264,
                                         dictionary_name="tag36h11")
    f.write_text("target_type: 'checkerboard'\ntargetCols: 8\ntargetRows: 6\n"
                 "rowSpacingMeters: 0.108\ncolSpacingMeters: 0.108\n")
    assert target_params(f) == {"board.type": "chessboard", "board.cols": 8, "board.rows": 6,
                                "board.square_length": 0.108}
    # Kalibr's circlegrid: asymmetricGrid false (or absent) is OpenCV's symmetric grid
    f.write_text("target_type: 'circlegrid'\ntargetCols: 6\ntargetRows: 7\n"
                 "spacingMeters: 0.02\nasymmetricGrid: False\n")
    assert Board.from_params(target_params(f)) == Board(board_type="circles", cols=6, rows=7,
                                                        square_length=0.02)
    f.write_text("target_type: 'circlegrid'\ntargetCols: 4\ntargetRows: 11\n"
                 "spacingMeters: 0.02\nasymmetricGrid: True\n")
    acircles = Board.from_params(target_params(f))
    assert acircles == Board(board_type="acircles", cols=4, rows=11, square_length=0.02)
    # Kalibr's asymmetric layout: point r * cols + c at ((2 c + r % 2) s, r s)
    r, c = np.divmod(np.arange(44), 4)
    np.testing.assert_allclose(acircles.object_points()[:, :2],
                               np.stack([(2 * c + r % 2) * 0.02, r * 0.02], axis=1), atol=1e-12)


@pytest.mark.parametrize(("text", "message"), [
    ("target_type: aprilgrid\ntagCols: 6\ntagSize: 0.088\ntagSpacing: 0.3\n", "needs tagRows"),
    ("target_type: aprilgrid\ntagCols: 6.5\ntagRows: 6\ntagSize: 0.08\ntagSpacing: 0.3\n",
     "tagCols: 6.5 is not an integer"),
    ("target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: -1\ntagSpacing: 0.3\n",
     "tagSize: -1 must be > 0"),
    ("target_type: checkerboard\ntargetCols: 6\ntargetRows: 7\nrowSpacingMeters: 0.06\n"
     "colSpacingMeters: 0.05\n", "differ"),
    ("target_type: circlegrid\ntargetCols: 6\n", "needs targetRows"),
    ("target_type: circlegrid\ntargetCols: 6\ntargetRows: 7\nspacingMeters: 0.02\n"
     "asymmetricGrid: maybe\n", "asymmetricGrid: 'maybe' is not true or false"),
    ("target_type: [\n", "not valid YAML"),
    ("- 1\n- 2\n", "expected a mapping"),
    ("target_type: apriltag\n", "not a Kalibr target type"),
])
def test_bad_kalibr_target_files_say_what_is_wrong(tmp_path: Path, text: str,
                                                  message: str,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    f = tmp_path / "t.yaml"
    f.write_text(text)
    with pytest.raises(ParameterError, match=message):
        target_params(f)
    assert main(["calibrate", "x.png", "--target", str(f), "--output",
                 str(tmp_path / "c.yaml"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert message.split(":")[0] in err and "Traceback" not in err



def test_overlay_draws_aprilgrid_detections() -> None:
    """(The live collection of aprilgrid views: test_boards_cli.py.)"""
    from artcal_ros.core.live.coverage import CoverageConfig, ViewCollector
    from artcal_ros.core.live.overlay import render_overlay

    view = _views(6, 0.0, 3)[0]
    collector = ViewCollector(APRIL, CoverageConfig(min_views=2))
    dets = Detector(APRIL).detect(view.image)
    drawn = render_overlay(view.image, dets, collector.counts(), collector.readiness())
    assert drawn.shape == (*view.image.shape, 3)
    assert np.any(drawn[..., 1] != drawn[..., 0])   # markers drawn in colour
