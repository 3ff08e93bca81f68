"""The calibration report (report.pdf, its pages as PNGs, summary.json) against the renderer's
truth: the files and page counts, what the plots are computed from (the other point type
checked with the solved camera, the distortion map against the true lens), and the first
page's words for a good and a poor calibration."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import CalibrationResult, calibrate
from artcal_ros.core.calibrate.report import point_kinds, write_refused_report, write_report
from artcal_ros.core.calibrate.report_plots import lens_displacement
from artcal_ros.core.calibrate.report_text import plain_verdict, refused_verdict
from artcal_ros.core.detections import Detections
from artcal_ros.synth import Camera, random_poses
from artcal_ros.synth.poses import marker_truth

BOARD = Board()
PAGES = ["verdict.png", "residuals.png", "residual_histogram.png", "uncertainty.png",
         "distortion.png", "coverage.png", "per_view_error.png", "intrinsics.png"]


def pdf_pages(path: Path) -> int:
    """Pages of a PDF: its /Type /Page objects (matplotlib writes no object streams)."""
    return len(re.findall(rb"/Type\s*/Page(?![a-zA-Z])", path.read_bytes()))


def exact_detections(cam: Camera, n: int, seed: int, noise_px: float = 0.03,
                     near_centre_px: float = 0.0) -> list[Detections]:
    """The board's true marker corners in ``n`` random views with Gaussian noise; with
    ``near_centre_px`` only the markers that close to the image centre."""
    rng = np.random.default_rng(seed)
    out = []
    for k, (rvec, tvec) in enumerate(random_poses(BOARD, cam, n, rng)):
        corners, centres, inside, _ = marker_truth(BOARD, cam, rvec, tvec)
        keep = inside.copy()
        if near_centre_px:
            keep &= np.linalg.norm(centres - np.array(cam.size) / 2, axis=1) < near_centre_px
        noisy = corners[keep] + rng.normal(0.0, noise_px, corners[keep].shape)
        out.append(Detections(BOARD.ids[keep], noisy, centres[keep], cam.size,
                              source=f"view{k:02d}.png"))
    return out


@pytest.fixture(scope="module")
def good() -> tuple[Camera, list[Detections], CalibrationResult]:
    cam = Camera.preset("webcam")
    dets = exact_detections(cam, 16, seed=21)
    return cam, dets, calibrate(dets, BOARD, image_size=cam.size, points="corners")


def test_report_files_pages_and_pngs(good: tuple[Camera, list[Detections], CalibrationResult],
                                     tmp_path: Path) -> None:
    _, dets, result = good
    tone = {"gamma": 2.2, "name": "gamma 2.2", "estimated": True, "sides": 300, "sigma": 0.04}
    check = {"marker_length": 0.06, "marker_separation": 0.0201, "views": 12, "warning": ""}
    written = write_report(tmp_path / "rep", result, tone_curve=tone, board_check=check,
                           detections=dets, board=BOARD, extra={"frames": len(dets)},
                           title="cam0")
    names = [p.name for p in written]
    assert names == ["report.pdf", *PAGES, "summary.json"]
    assert pdf_pages(tmp_path / "rep" / "report.pdf") == len(PAGES)
    for name in PAGES:
        image = cv2.imread(str(tmp_path / "rep" / name))
        assert image is not None and image.shape == (750, 1100, 3), name
        assert image.std() > 10, name  # not blank
    summary = json.loads((tmp_path / "rep" / "summary.json").read_text())
    assert summary["success"] is True and summary["frames"] == len(dets)
    assert summary["tone_curve"] == tone and summary["board_check"] == check
    assert summary["projection_uncertainty_px"]["rms"] == result.projection_uncertainty_rms_px
    assert not list((tmp_path / "rep").glob(".*.tmp"))  # every file renamed into place


def test_the_other_point_type_is_checked_with_the_solved_camera(
        good: tuple[Camera, list[Detections], CalibrationResult]) -> None:
    _, dets, result = good
    kinds = point_kinds(result, dets, BOARD)
    assert list(kinds) == ["marker corners (solved from)", "marker centres (checked)"]
    centres = kinds["marker centres (checked)"]
    # the true centres are given, so they land within the solved camera's own error
    assert len(centres) == sum(len(dets[i].ids) for i in result.views_used)
    rms = float(np.sqrt(np.mean(np.sum(centres ** 2, axis=1))))
    assert rms < 0.05
    # a camera 1 % off in focal length moves them by pixels: the check can fail
    K = result.camera_matrix.copy()
    K[0, 0] *= 1.01
    off = point_kinds(replace(result, camera_matrix=K), dets, BOARD)["marker centres (checked)"]
    assert np.sqrt(np.mean(np.sum(off ** 2, axis=1))) > 5 * rms


def test_distortion_map_matches_the_true_lens(
        good: tuple[Camera, list[Detections], CalibrationResult]) -> None:
    cam, _, result = good
    w, h = cam.size
    pix = np.array([[0.0, 0.0], [w - 1.0, h - 1.0], [w / 2, 10.0], [cam.K[0, 2], cam.K[1, 2]]])
    est = lens_displacement(result.camera, pix)
    # the truth: where the true lens puts each pixel's ray against its pinhole image
    rays, _ = cam.unproject(pix)
    true = pix - (rays[:, :2] * [cam.K[0, 0], cam.K[1, 1]] + cam.K[:2, 2])
    assert np.linalg.norm(true[0]) > 20  # the webcam's corners move tens of pixels
    assert np.allclose(est, true, atol=0.3)
    assert np.linalg.norm(est[3]) < 1e-6  # none at the principal point


def test_first_page_words_good_and_poor(
        good: tuple[Camera, list[Detections], CalibrationResult]) -> None:
    cam, _, result = good
    words = plain_verdict(result)
    assert words.level == "good" and words.headline.startswith("GOOD")
    assert words.actions == () and "Nothing needs to be done" in words.meaning
    # five views with only the markers near the centre: the figures are good, but the
    # corners are not covered and 5 views are few: good with reservations, and what to add
    near = exact_detections(cam, 5, seed=13, near_centre_px=150)
    weak = calibrate(near, BOARD, image_size=cam.size, points="corners")
    words = plain_verdict(weak)
    assert words.headline.startswith("GOOD, with reservations")
    text = words.text()
    assert f"Only {100 * weak.coverage:.0f}% of the image" in text
    assert "15-20" in text and words.notes == weak.warnings
    # the same with 0.6 px noise: the fit is worse and the camera poorly known
    noisy = exact_detections(cam, 5, seed=13, noise_px=0.6, near_centre_px=150)
    poor = calibrate(noisy, BOARD, image_size=cam.size, points="corners")
    words = plain_verdict(poor)
    assert words.level == "poor" and words.headline.startswith("POOR"), words.text()
    text = words.text()
    assert "tilted" in text and "image corners" in text     # what pictures to add
    assert "board settings" in text                          # the fit is poor
    # a board whose settings are wrong: the fit itself is poor, and the advice says to check it
    bad = plain_verdict(replace(result, reprojection_rms_px=2.0),
                        board_check={"warning": "separation 0.025 m, not 0.020 m"})
    assert bad.level == "poor" and bad.headline.startswith("POOR")
    assert any("board settings" in a for a in bad.actions)
    assert any("printed board does not match" in a for a in bad.actions)
    assert "board check: separation 0.025 m" in bad.notes[-1]


def test_a_refused_set_gets_the_reason_and_the_coverage(tmp_path: Path) -> None:
    reason = "all views show the board at the same angle: add views tilted 20-40 deg"
    points = np.random.default_rng(1).uniform([0, 0], [640, 480], (300, 2))
    written = write_refused_report(tmp_path, reason, (640, 480), points, images=4,
                                   summary={"success": False, "reason": reason})
    assert [p.name for p in written] == ["report.pdf", "verdict.png", "coverage.png",
                                         "summary.json"]
    assert pdf_pages(tmp_path / "report.pdf") == 2
    words = refused_verdict(reason, images=4, points=300)
    assert words.level == "refused" and words.meaning.endswith(f"Why: {reason}")
    assert "4 read, 300 board points found" in words.text()
    for name in ("verdict.png", "coverage.png"):
        image = cv2.imread(str(tmp_path / name))
        assert image is not None and image.shape == (750, 1100, 3)


def test_a_rig_report_has_a_page_per_pair(tmp_path: Path) -> None:
    from artcal_ros.core.calibrate.rig import calibrate_rig
    from artcal_ros.core.calibrate.rig_report import rig_verdict_words, write_rig_report
    from test.unit.rig_synth import BOARD as RIG_BOARD
    from test.unit.rig_synth import make_rig

    _, dets = make_rig("trio", "webcam", 10, seed=5)
    rig = calibrate_rig(dets, RIG_BOARD, image_sizes={n: (640, 480) for n in dets})
    written = write_rig_report(tmp_path, rig, dets, RIG_BOARD, "corners")
    pairs = [f"pair_{a}_{b}.png" for a, b in rig.rectification]
    assert len(pairs) == 2
    per_camera = PAGES[1:]
    assert [p.name for p in written[:2 + len(pairs)]] == ["report.pdf", "verdict.png", *pairs]
    assert pdf_pages(tmp_path / "report.pdf") == 1 + len(pairs) + 3 * len(per_camera)
    for n in rig.names:
        assert sorted(p.name for p in (tmp_path / n).glob("*.png")) == sorted(per_camera)
    page = cv2.imread(str(tmp_path / pairs[0]))
    assert page is not None and page.shape == (750, 1100, 3)
    words = rig_verdict_words(rig, RIG_BOARD)
    assert words.level == "good", words.text()
    assert [k for k, _ in words.figures][:3] == [f"camera {n}" for n in rig.names]


def test_cli_report_of_rendered_frames(tmp_path: Path) -> None:
    from artcal_ros.cli.main import main
    from artcal_ros.synth import Photometry, render_view

    cam = Camera.preset("webcam")
    rng = np.random.default_rng(4)
    images = []
    for k, (rvec, tvec) in enumerate(random_poses(BOARD, cam, 5, rng, partial_fraction=0.2)):
        view = render_view(BOARD, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
        images.append(str(tmp_path / f"view{k}.png"))
        cv2.imwrite(images[-1], view.image)
    report = tmp_path / "report"
    assert main(["calibrate", *images, "--output", str(tmp_path / "c.yaml"), "--report",
                 str(report), "--quiet"]) == 0
    assert pdf_pages(report / "report.pdf") == len(PAGES)
    assert sorted(p.name for p in report.glob("*.png")) == sorted(PAGES)
    summary = json.loads((report / "summary.json").read_text())
    assert {"tone_curve", "board_check", "projection_uncertainty_px", "sources_used"} <= set(
        summary)
    # one picture: no calibration (exit 1), and still a report saying why
    refused = tmp_path / "refused"
    assert main(["calibrate", images[0], "--output", str(tmp_path / "d.yaml"), "--report",
                 str(refused), "--quiet"]) == 1
    assert pdf_pages(refused / "report.pdf") == 2
    assert sorted(p.name for p in refused.glob("*.png")) == ["coverage.png", "verdict.png"]


def test_a_refused_rig_has_each_cameras_coverage(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    left = rng.uniform([0, 0], [640, 480], (200, 2))
    wall = np.zeros((0, 2))  # a camera that saw nothing
    written = write_refused_report(tmp_path, "camera wall is not connected to the rig",
                                   (640, 480), left, images=10, title="left",
                                   more_cameras={"wall": ((1280, 720), wall)})
    assert [p.name for p in written] == ["report.pdf", "verdict.png", "coverage.png",
                                         "coverage_wall.png"]
    assert pdf_pages(tmp_path / "report.pdf") == 3
    wall_page = cv2.imread(str(tmp_path / "coverage_wall.png"))
    assert wall_page is not None and wall_page.shape == (750, 1100, 3)


def test_views_left_out_are_grouped_by_reason() -> None:
    from artcal_ros.core.calibrate.report_text import dropped_kinds
    from artcal_ros.core.calibrate.result import DroppedView

    dropped = [DroppedView(1, "a.png", "3 marker(s), needs at least 6"),
               DroppedView(4, "b.png", "not selected (similar views kept)"),
               DroppedView(5, "c.png", "0 marker(s), needs at least 6"),
               DroppedView(9, "d.png", "not selected (similar views kept)"),
               DroppedView(12, "e.png", "not selected (similar views kept)")]
    kinds = dropped_kinds(dropped)
    assert list(kinds) == ["not selected (similar views kept)", "N marker(s), needs at least N"]
    assert [d.view_index for d in kinds["N marker(s), needs at least N"]] == [1, 5]
