"""Marker detection against the renderer's exact truth (fixed seeds; full figures in bench/).

Tolerances sit above the measured values with margin (see docs/benchmarks.md):
clean corners measure ~0.02 px RMS, noisy and blurred ones ~0.06 px.
"""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from artcal_ros.cli.main import main as artcal_main
from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, DetectorConfig, detect
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import DetectionError
from artcal_ros.synth import Camera, Photometry, RenderedView, random_poses, render_view

CAM = Camera.preset("webcam")


def _views(board: Board, n: int, seed: int, phot: Photometry, *, partial: float = 0.3,
           encoding: str = "mono8") -> list[RenderedView]:
    rng = np.random.default_rng(seed)
    return [render_view(board, CAM, r, t, photometry=phot, rng=rng, encoding=encoding)
            for r, t in random_poses(board, CAM, n, rng, partial_fraction=partial)]


def _score(views: list[RenderedView], dets: list[Detections], board: Board
           ) -> tuple[np.ndarray, np.ndarray, float]:
    """Corner errors, center errors (markers >= 20 px) and recall (inside, >= 15 px)."""
    corner, center, want, found = [], [], 0, 0
    for v, d in zip(views, dets, strict=True):
        k = d.ids - board.first_id
        assert v.inside[k].all(), "a marker not fully in the image was reported"
        good = v.side_px[k] >= 20
        corner.append(np.linalg.norm(d.corners_px - v.corners_px[k], axis=2)[good].ravel())
        center.append(np.linalg.norm(d.centers_px - v.centers_px[k], axis=1)[good])
        w = v.inside & (v.side_px >= 15)
        want += int(w.sum())
        found += int((w & np.isin(v.ids, d.ids)).sum())
    return np.concatenate(corner), np.concatenate(center), found / max(want, 1)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.fixture(scope="module")
def clean_set() -> tuple[Board, list[RenderedView], list[Detections]]:
    board = Board()
    views = _views(board, 3, 4242, Photometry.clean())
    det = Detector(board)
    return board, views, [det.detect(v.image) for v in views]


def test_clean_corners_and_centers_are_accurate(clean_set) -> None:
    board, views, dets = clean_set
    corner, center, recall = _score(views, dets, board)
    assert len(corner) > 100
    assert _rms(corner) < 0.045
    assert np.percentile(corner, 95) < 0.09
    assert _rms(center) < 0.045
    assert recall >= 0.99
    # every reported sigma is a positive, plausible number of the right order
    sig = np.concatenate([d.corner_sigma_px.ravel() for d in dets])
    assert np.all(np.isfinite(sig)) and np.all(sig > 0) and np.median(sig) < 0.1


def test_at_least_three_times_better_than_plain_opencv(clean_set) -> None:
    board, views, dets = clean_set
    ours = _rms(_score(views, dets, board)[0])
    for refine in (cv2.aruco.CORNER_REFINE_NONE, cv2.aruco.CORNER_REFINE_SUBPIX,
                   cv2.aruco.CORNER_REFINE_CONTOUR):
        p = cv2.aruco.DetectorParameters()
        p.cornerRefinementMethod = refine
        cv = cv2.aruco.ArucoDetector(board.dictionary, p)
        errs = []
        for v in views:
            corners, ids, _ = cv.detectMarkers(v.image)
            ids = np.asarray(ids).ravel()
            c = np.asarray(corners).reshape(-1, 4, 2)
            errs.append(np.linalg.norm(c - v.corners_px[ids], axis=2)[v.side_px[ids] >= 20])
        assert ours * 3.0 <= _rms(np.concatenate(errs)), refine


def test_noisy_blurred_corners() -> None:
    board = Board()
    phot = Photometry(defocus_px=1.8, full_well=1500.0, read_noise=12.0)
    views = _views(board, 2, 777, phot)
    det = Detector(board)
    corner, center, recall = _score(views, [det.detect(v.image) for v in views], board)
    assert _rms(corner) < 0.10
    assert _rms(center) < 0.10
    # small markers under this much blur lose their code cells: recall ~96 % (bench/)
    assert recall >= 0.94


@pytest.mark.parametrize("polarity", ["white", "mixed"])
def test_other_polarities(polarity: str) -> None:
    board = Board(polarity=polarity)
    views = _views(board, 1, 31337, Photometry.clean(), partial=0.0)
    corner, _, recall = _score(views, [detect(views[0].image, board)], board)
    assert recall >= 0.98
    assert _rms(corner) < 0.05  # also proves the corner order on white markers


def test_white_borders_as_accurate_as_black_under_defocus() -> None:
    """The same pose, blurred, as a black board and as its photographic negative.

    The quad finder's corners sit up to 2 px outside a white border (inside a
    black one); the refined corners must not inherit that.
    """
    rng = np.random.default_rng(2718)
    rvec, tvec = random_poses(Board(), CAM, 1, rng, partial_fraction=0.0)[0]
    phot = Photometry(defocus_px=1.4, noise=False)
    rms = {}
    for polarity in ("black", "white"):
        board = Board(polarity=polarity)
        view = render_view(board, CAM, rvec, tvec, photometry=phot,
                           rng=np.random.default_rng(1))
        corner, center, recall = _score([view], [detect(view.image, board)], board)
        assert len(corner) > 40 and recall >= 0.98
        rms[polarity] = _rms(corner)
        assert _rms(center) < 0.035, polarity
    assert rms["black"] < 0.035
    assert rms["white"] < 1.3 * rms["black"] + 0.003, rms


def test_jitter_is_small() -> None:
    board = Board(cols=8, rows=5)
    rng = np.random.default_rng(99)
    rvec, tvec = random_poses(board, CAM, 1, rng, partial_fraction=0.0)[0]
    det = Detector(board)
    runs = [det.detect(render_view(board, CAM, rvec, tvec, rng=rng).image) for _ in range(6)]
    common = set.intersection(*(set(d.ids.tolist()) for d in runs))
    assert len(common) >= 30
    stack = np.stack([d.corners_px[np.isin(d.ids, sorted(common))] for d in runs])
    assert _rms(stack.std(axis=0)) < 0.03


def test_no_ids_from_clutter_or_partial_views() -> None:
    board = Board(polarity="mixed")
    det = Detector(board)
    rng = np.random.default_rng(2024)
    for _ in range(8):  # only the cluttered background: the board is behind the camera
        view = render_view(board, CAM, rng.normal(0, 0.3, 3), np.array([0.0, 0.0, -2.0]),
                           rng=rng)
        assert len(det.detect(view.image)) == 0
    for view in _views(board, 2, 555, Photometry.clean(), partial=1.0):
        d = det.detect(view.image)
        k = d.ids - board.first_id
        assert view.inside[k].all()
        assert np.abs(d.corners_px - view.corners_px[k]).max() < 0.5


def test_second_pass_with_the_camera_model_and_16_bit_input() -> None:
    board = Board()
    views = _views(board, 1, 8080, Photometry.clean(), partial=0.0, encoding="mono16")
    det = Detector(board, DetectorConfig(gamma_16bit=2.2))
    corner, center, recall = _score(views, [det.detect(views[0].image, camera=CAM)], board)
    assert recall >= 0.98
    assert _rms(corner) < 0.045
    assert _rms(center) < 0.045


def test_colour_input_and_bad_input() -> None:
    board = Board(cols=6, rows=4)
    view = _views(board, 1, 7, Photometry.clean(), partial=0.0, encoding="bgr8")[0]
    d = detect(view.image, board)
    assert len(d) == 24
    with pytest.raises(DetectionError, match="uint8 or uint16"):
        detect(view.image.astype(np.float32), board)
    with pytest.raises(DetectionError, match="shape"):
        detect(np.zeros((4, 4, 2), np.uint8), board)
    assert len(detect(np.full((120, 160), 128, np.uint8), board)) == 0


def test_cli_json_overlay_and_unreadable_file(tmp_path: Path, capsys) -> None:
    board = Board(cols=6, rows=4)
    view = _views(board, 1, 11, Photometry.clean(), partial=0.0)[0]
    img = tmp_path / "frame.png"
    cv2.imwrite(str(img), view.image)
    out = tmp_path / "dets.json"
    rc = artcal_main(["detect", str(img), "--set", "board.cols=6", "--set", "board.rows=4",
                      "--json", str(out), "--overlay", str(tmp_path / "ov"), "--quiet"])
    assert rc == 0
    doc = json.loads(out.read_text())
    rec = doc["images"][0]
    assert rec["file"] == str(img) and (rec["width"], rec["height"]) == CAM.size
    assert len(rec["markers"]) == 24
    m = rec["markers"][0]
    assert set(m) == {"id", "corners", "center"} and len(m["corners"]) == 4
    back = Detections.from_json(rec)
    assert np.abs(back.corners_px - view.corners_px[back.ids]).max() < 0.2
    assert (tmp_path / "ov" / "frame.png").is_file()
    bad = tmp_path / "broken.png"
    bad.write_bytes(b"not a png")
    rc = artcal_main(["detect", str(bad), "--json", str(tmp_path / "x.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "broken.png" in err and "Traceback" not in err


def test_lens_models_round_trip() -> None:
    from artcal_ros.core.detect.lens import DivisionLens, known_lens

    pts = np.random.default_rng(3).uniform([0, 0], [640, 480], (50, 2))
    for lens in (known_lens(CAM), DivisionLens(-0.2, np.array([320.0, 240.0]), 400.0,
                                                       0.03)):
        back = lens.distort(lens.undistort(pts))
        assert np.abs(back - pts).max() < 1e-6
    with pytest.raises(DetectionError, match="camera"):
        known_lens(object())  # type: ignore[arg-type]
