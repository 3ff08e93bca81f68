"""Calibration from marker correspondences: accuracy against a known camera, degenerate
sets, outliers, view selection, uncertainty, report and the ``artcal calibrate`` verb."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from artcal_ros.cli.main import main
from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import calibrate
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.calibrate.solve import ViewPoints
from artcal_ros.core.calibrate.views import select_views, view_points
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import CalibrationError, ParameterError
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
from artcal_ros.synth.poses import marker_truth, smooth_poses

BOARD = Board()


def diagonal_centers(corners: np.ndarray) -> np.ndarray:
    """Centres as a detector without a lens model measures them: (M, 4, 2) -> (M, 2)."""
    h = np.concatenate([corners, np.ones((*corners.shape[:2], 1))], axis=2)
    c = np.cross(np.cross(h[:, 0], h[:, 2]), np.cross(h[:, 1], h[:, 3]))
    return c[:, :2] / c[:, 2:3]


def detections_from_poses(cam: Camera, poses: list, rng: np.random.Generator,
                          noise_px: float) -> list[Detections]:
    """Exact marker images with Gaussian corner noise; centres from the noisy corners.

    0.03 px is the corner jitter the source paper measured for its detector (640 x 480,
    good light and focus).
    """
    out = []
    for k, (rvec, tvec) in enumerate(poses):
        corners, _, inside, _ = marker_truth(BOARD, cam, rvec, tvec)
        noisy = corners[inside] + rng.normal(0.0, noise_px, corners[inside].shape)
        out.append(Detections(BOARD.ids[inside], noisy, diagonal_centers(noisy), cam.size,
                              source=f"view{k}"))
    return out


def truth_detections(preset: str, n: int, seed: int,
                     noise_px: float = 0.03) -> tuple[Camera, list[Detections]]:
    cam = Camera.preset(preset)
    rng = np.random.default_rng(seed)
    return cam, detections_from_poses(cam, random_poses(BOARD, cam, n, rng), rng, noise_px)


# --- accuracy --------------------------------------------------------------------------------
@pytest.mark.parametrize("points", ["centers", "corners"])
def test_webcam_accuracy_and_honest_uncertainty(points: str) -> None:
    cam, dets = truth_detections("webcam", 20, seed=11)
    r = calibrate(dets, BOARD, image_size=cam.size, points=points)
    rms, worst = projection_difference(cam, r)
    assert rms <= 0.05 and worst <= 0.15, (rms, worst)
    # The reported 1-sigma must describe the real error (within 5 sigma).
    for name, true in (("fx", cam.K[0, 0]), ("fy", cam.K[1, 1]), ("cx", cam.K[0, 2]),
                       ("cy", cam.K[1, 2])):
        est = {"fx": r.camera_matrix[0, 0], "fy": r.camera_matrix[1, 1],
               "cx": r.camera_matrix[0, 2], "cy": r.camera_matrix[1, 2]}[name]
        assert abs(est - true) < 5 * r.std_devs[name] + 1e-3, (name, est, true, r.std_devs)
    # The error against the truth is of the size the reported uncertainty announces.
    assert rms < 3 * r.projection_uncertainty_rms_px
    # Corner noise 0.03 px per axis: the fit and the hold-out error must say so.
    assert 0.01 < r.reprojection_std_px < 0.05
    assert r.holdout_rms_px < 1.3 * r.reprojection_rms_px + 0.01
    assert r.views_used == tuple(range(20)) and not r.views_dropped
    assert r.dist_coeffs.shape == (5,) and r.dist_coeffs[4] == 0.0  # k3 held at zero


def test_fisheye_equidistant_accuracy() -> None:
    cam, dets = truth_detections("fisheye", 15, seed=5)
    r = calibrate(dets, BOARD, image_size=cam.size, model="equidistant", points="corners",
                  cross_validation_folds=0)
    rms, _ = projection_difference(cam, r)
    assert rms <= 0.2, rms
    assert r.dist_coeffs.shape == (4,)
    assert set(r.std_devs) == {"fx", "fy", "cx", "cy", "k1", "k2", "k3", "k4"}


def test_projection_difference_is_zero_for_the_true_camera_and_sees_a_shift() -> None:
    cam = Camera.preset("wide")
    assert projection_difference(cam, cam)[1] < 1e-6
    other = Camera(cam.model, cam.K + np.array([[0, 0, 0.5], [0, 0, 0], [0, 0, 0]]),
                   cam.dist, cam.size)
    rms, worst = projection_difference(cam, other)
    assert rms == pytest.approx(0.5, abs=1e-6) and worst == pytest.approx(0.5, abs=1e-6)


# --- solve options (the calibrate.* parameters) ---------------------------------------------
def constrained_truth() -> Camera:
    """A lens that obeys every solve constraint: fx = fy, principal point at the image centre
    ((w - 1) / 2, (h - 1) / 2), p1 = p2 = 0, k3 = 0."""
    w, h = 640, 480
    K = np.array([[600.0, 0.0, (w - 1) / 2.0], [0.0, 600.0, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    return Camera("plumb_bob", K, np.array([-0.35, 0.15, 0.0, 0.0, 0.0]), (w, h))


@pytest.mark.parametrize("option", ["fix_principal_point", "fix_aspect_ratio",
                                    "zero_tangent_dist"])
def test_solve_option_holds_exactly_and_finds_the_true_camera(option: str) -> None:
    cam = constrained_truth()
    rng = np.random.default_rng(31)
    dets = detections_from_poses(cam, random_poses(BOARD, cam, 12, rng), rng, 0.03)
    free = calibrate(dets, BOARD, image_size=cam.size, cross_validation_folds=0)
    r = calibrate(dets, BOARD, image_size=cam.size, cross_validation_folds=0, **{option: True})
    K, d = r.camera_matrix, r.dist_coeffs
    held = {"fix_principal_point": ("cx", "cy"), "fix_aspect_ratio": ("fy",),
            "zero_tangent_dist": ("p1", "p2")}[option]
    if option == "fix_principal_point":
        assert (K[0, 2], K[1, 2]) == (319.5, 239.5)
    elif option == "fix_aspect_ratio":
        assert K[0, 0] == K[1, 1] and "f" in r.free
        assert r.std_devs["fx"] == r.std_devs["fy"] > 0
    else:
        assert d[2] == 0.0 and d[3] == 0.0
    assert not set(held) & set(r.free)
    # Without it the other parameters are untouched: the free solve does not hold them.
    assert free.camera_matrix[0, 2] != 319.5 and free.camera_matrix[0, 0] != free.camera_matrix[
        1, 1] and free.dist_coeffs[2] != 0.0
    # The truth obeys the constraint, so the held solve is as close to it as the free one
    # (0.03 px corner noise gives ~0.03 px) and as honest about it.
    rms = projection_difference(cam, r)[0]
    assert rms < 0.05 and rms < 3 * r.projection_uncertainty_rms_px + 0.01, rms
    for name, true in (("fx", 600.0), ("cx", 319.5), ("cy", 239.5)):
        if name in r.std_devs:
            est = {"fx": K[0, 0], "cx": K[0, 2], "cy": K[1, 2]}[name]
            assert abs(est - true) < 5 * r.std_devs[name] + 1e-3, (name, est)


def test_k_coefficients_frees_exactly_the_radial_terms_asked_for() -> None:
    cam, dets = truth_detections("wide", 15, seed=7)  # the wide lens has k3 = -0.012
    two = calibrate(dets, BOARD, image_size=cam.size, k_coefficients=2, cross_validation_folds=0)
    three = calibrate(dets, BOARD, image_size=cam.size, k_coefficients=3,
                      cross_validation_folds=0)
    alias = calibrate(dets, BOARD, image_size=cam.size, k3=True, cross_validation_folds=0)
    assert two.dist_coeffs[4] == 0.0 and "k3" not in two.std_devs
    assert three.dist_coeffs[4] == pytest.approx(-0.012, abs=0.001) and "k3" in three.std_devs
    assert projection_difference(cam, three)[0] < 0.05 < 1.0 < projection_difference(cam, two)[0]
    assert np.array_equal(alias.camera_matrix, three.camera_matrix)
    assert np.array_equal(alias.dist_coeffs, three.dist_coeffs)
    # (k1 alone cannot describe the wide lens: the solve refuses it; the webcam's it can fit)
    cam, dets = truth_detections("webcam", 12, seed=11)
    one = calibrate(dets, BOARD, image_size=cam.size, k_coefficients=1, cross_validation_folds=0)
    assert set(one.free) == {"fx", "fy", "cx", "cy", "k1", "p1", "p2"}
    assert one.dist_coeffs[1] == 0.0 and one.dist_coeffs[4] == 0.0 and one.dist_coeffs[0] < 0


@pytest.mark.parametrize(("model", "k", "zero"), [("equidistant", 2, (2, 3)),
                                                   ("rational_polynomial", 3, (5, 6, 7))])
def test_k_coefficients_for_the_other_models(model: str, k: int, zero: tuple[int, ...]) -> None:
    preset = "fisheye" if model == "equidistant" else "wide"
    base = Camera.preset(preset)
    dist = base.dist if model == "equidistant" else np.concatenate([base.dist, np.zeros(3)])
    cam = Camera(model, base.K, dist, base.size)  # rational: the wide lens, k4..k6 = 0
    rng = np.random.default_rng(9)
    dets = detections_from_poses(cam, random_poses(BOARD, cam, 12, rng), rng, 0.03)
    r = calibrate(dets, BOARD, image_size=cam.size, model=model, k_coefficients=k,
                  cross_validation_folds=0)
    assert all(r.dist_coeffs[i] == 0.0 for i in zero)
    assert all(r.dist_coeffs[i] != 0.0 for i in range(len(r.dist_coeffs)) if i not in zero)
    if model == "rational_polynomial":  # the truth has k4..k6 = 0: still on it
        assert projection_difference(cam, r)[0] < 0.05


def test_k_coefficients_out_of_range_is_refused() -> None:
    cam, dets = truth_detections("webcam", 4, seed=2)
    with pytest.raises(ParameterError, match=r"calibrate\.k_coefficients.*1 to 3"):
        calibrate(dets, BOARD, image_size=cam.size, k_coefficients=4)


# --- degenerate sets -------------------------------------------------------------------------
def test_one_view_is_refused_with_what_to_add() -> None:
    cam, dets = truth_detections("webcam", 1, seed=2)
    with pytest.raises(CalibrationError, match=r"1 usable view.*at least 3"):
        calibrate(dets, BOARD, image_size=cam.size)


def test_parallel_views_are_refused() -> None:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(3)
    rvec, tvec = random_poses(BOARD, cam, 1, rng, partial_fraction=0.0)[0]
    # The same board orientation, moved about: every board plane is parallel.
    poses = [(rvec, tvec + np.array([dx, dy, dz]))
             for dx, dy, dz in [(0, 0, 0), (0.05, 0, 0.05), (-0.05, 0.03, 0.1), (0.02, -0.04, 0),
                                (0, 0.05, 0.15), (-0.03, -0.02, 0.08)]]
    dets = detections_from_poses(cam, poses, rng, 0.05)
    with pytest.raises(CalibrationError, match="same angle"):
        calibrate(dets, BOARD, image_size=cam.size)


def test_single_marker_per_view_is_refused() -> None:
    cam, dets = truth_detections("webcam", 8, seed=4)
    single = [d.subset(np.array([len(d) // 2])) for d in dets]
    with pytest.raises(CalibrationError, match=r"1 marker\(s\), needs at least 6"):
        calibrate(single, BOARD, image_size=cam.size, points="corners")


def test_too_few_points_is_refused() -> None:
    cam, dets = truth_detections("webcam", 8, seed=4)
    few = [d.subset(np.arange(min(3, len(d)))) for d in dets]
    with pytest.raises(CalibrationError, match="needs at least 6"):
        calibrate(few, BOARD, image_size=cam.size)


def test_markers_on_one_board_row_are_refused() -> None:
    cam, dets = truth_detections("webcam", 6, seed=8)
    rows = [d.subset(np.array([BOARD.cell_of(int(i))[0] == BOARD.cell_of(int(d.ids[0]))[0]
                               for i in d.ids])) for d in dets]
    with pytest.raises(CalibrationError, match="one line of the board"):
        calibrate(rows, BOARD, image_size=cam.size)


def test_wrong_board_description_is_an_error_not_a_camera() -> None:
    cam, dets = truth_detections("webcam", 10, seed=9)
    wrong = Board(cols=20, rows=9)  # ids land on the wrong cells
    with pytest.raises(CalibrationError, match=r"board\.cols"):
        calibrate(dets, wrong, image_size=cam.size)


def test_wrong_marker_length_is_an_error_with_corners() -> None:
    cam, dets = truth_detections("webcam", 10, seed=9)
    wrong = Board(marker_length=0.05, marker_separation=0.03)  # same pitch, other squares
    with pytest.raises(CalibrationError, match="board parameters"):
        calibrate(dets, wrong, image_size=cam.size, points="corners")


@pytest.mark.parametrize(("preset", "seed", "model"), [("webcam", 7210, "plumb_bob"),
                                                       ("fisheye", 7210, "equidistant"),
                                                       ("fisheye", 7211, "equidistant")])
def test_true_points_of_strongly_distorted_views_are_all_kept(preset: str, seed: int,
                                                              model: str) -> None:
    """Close views through strong distortion bend the grid within a few cells: the layout
    check must not take true markers there for misplaced ones (over two cells it dropped
    44 - 352 true points and, on the fisheye, whole views as another board's)."""
    cam, dets = truth_detections(preset, 20, seed=seed, noise_px=0.0)
    r = calibrate(dets, BOARD, image_size=cam.size, model=model, points="corners")
    assert r.points_dropped == 0 and not r.views_dropped
    assert projection_difference(cam, r)[0] < 1e-3


# --- outliers --------------------------------------------------------------------------------
def test_outlier_point_and_view_are_dropped_and_reported() -> None:
    cam, dets = truth_detections("webcam", 16, seed=12)
    clean = calibrate([d for k, d in enumerate(dets) if k != 7], BOARD, image_size=cam.size,
                      points="centers", cross_validation_folds=0)
    corners = dets[3].corners_px.copy()
    corners[5] += np.array([6.0, -4.0])  # one marker badly located
    dets[3] = Detections(dets[3].ids, corners, diagonal_centers(corners), cam.size,
                         source="view3")
    bad = dets[7]  # a view whose ids are all wrong (e.g. another board)
    shuffled = np.random.default_rng(0).permutation(bad.ids)
    dets[7] = Detections(shuffled, bad.corners_px, bad.centers_px, cam.size, source="view7")
    r = calibrate(dets, BOARD, image_size=cam.size, points="centers")
    assert [d.view_index for d in r.views_dropped] == [7] and 3 in r.views_used
    assert r.points_dropped >= 1
    # (reported where it was measured, after correcting centres for the lens: within 2 px)
    moved = diagonal_centers(corners)[5]
    assert np.min(np.linalg.norm(r.outliers_px - moved, axis=1)) < 2.0
    # The outliers left no trace: the same camera as without them, to 0.01 px.
    assert projection_difference(clean, r)[1] < 0.01
    assert r.reprojection_max_px < 0.5


# --- view selection --------------------------------------------------------------------------
def test_selection_beats_consecutive_frames() -> None:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(21)
    poses = smooth_poses(BOARD, cam, 100, rng, frames_per_key=10)
    dets = detections_from_poses(cam, poses, rng, 0.03)
    views = [view_points(d, BOARD, "corners", k) for k, d in enumerate(dets)]
    chosen = select_views(views, cam.size, 20)
    assert len(chosen) == 20 and len(set(chosen)) == 20
    auto = calibrate(dets, BOARD, image_size=cam.size, max_views=20, cross_validation_folds=0)
    assert sorted(auto.views_used) == chosen
    assert sum(d.reason.startswith("not selected") for d in auto.views_dropped) == 80
    naive = calibrate(dets[:20], BOARD, image_size=cam.size, cross_validation_folds=0)
    sel_rms = projection_difference(cam, auto)[0]
    naive_rms = projection_difference(cam, naive)[0]
    # 20 diverse views of a sweep beat its first 20 frames, and are as good as they say.
    assert sel_rms < naive_rms, (sel_rms, naive_rms)
    assert sel_rms < 3 * auto.projection_uncertainty_rms_px and sel_rms < 0.1


def test_selection_prefers_diverse_views() -> None:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(5)
    base = random_poses(BOARD, cam, 4, rng, partial_fraction=0.0)
    # 40 near-copies of the first pose, then the three other poses once each.
    poses = [(base[0][0] + rng.normal(0, 1e-3, 3), base[0][1]) for _ in range(40)] + base[1:]
    dets = detections_from_poses(cam, poses, rng, 0.05)
    views: list[ViewPoints] = [view_points(d, BOARD, "centers", k) for k, d in enumerate(dets)]
    chosen = select_views(views, cam.size, 4)
    assert {40, 41, 42} <= set(chosen)


# --- summary, warnings, report ---------------------------------------------------------------
def test_summary_and_weak_data_warnings(tmp_path: Path) -> None:
    cam, dets = truth_detections("webcam", 5, seed=13)
    # Keep only markers near the image centre: the corners are not covered.
    center = np.array(cam.size) / 2.0
    near = [d.subset(np.linalg.norm(d.centers_px - center, axis=1) < 150) for d in dets]
    r = calibrate(near, BOARD, image_size=cam.size, points="corners")
    text = " ".join(r.warnings)
    # both weaknesses are named: the uncovered image and the few views actually used
    assert "points cover only" in text and "(8x6 grid)" in text
    assert f"only {len(r.views_used)} views;" in text and len(r.views_used) <= 5
    summary = json.loads(json.dumps(r.to_summary_dict()))
    assert summary["views_used"] == list(r.views_used)
    assert set(summary["std_devs"]) >= {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2"}
    assert "fx" in r.summary_line()

    from artcal_ros.core.calibrate.report import write_plots

    for path in write_plots(tmp_path, r):
        image = cv2.imread(str(path))
        assert image is not None and image.shape[0] > 100 and image.std() > 5


# --- the artcal calibrate verb ---------------------------------------------------------------
def _render_pngs(directory: Path, n: int, seed: int) -> list[str]:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(seed)
    paths = []
    for k, (rvec, tvec) in enumerate(random_poses(BOARD, cam, n, rng, partial_fraction=0.2)):
        view = render_view(BOARD, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
        path = directory / f"view{k:02d}.png"
        cv2.imwrite(str(path), view.image)
        paths.append(str(path))
    return paths


def test_cli_single_view_exits_1_and_keeps_the_old_file(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture) -> None:
    image = _render_pngs(tmp_path, 1, seed=1)
    out = tmp_path / "camera.yaml"
    out.write_text("good: calibration\n")
    code = main(["calibrate", *image, "--output", str(out), "--quiet"])
    assert code == 1
    assert "at least 3" in capsys.readouterr().err
    assert out.read_text() == "good: calibration\n"


def test_cli_bad_parameter_exits_2_naming_it(tmp_path: Path,
                                            capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "camera.yaml"
    code = main(["calibrate", "missing.png", "--set", "board.cols=-1", "--output", str(out)])
    assert code == 2
    assert "board.cols" in capsys.readouterr().err
    assert not out.exists()


def test_cli_calibrates_images_and_writes_report(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture) -> None:
    from artcal_ros.core.camera_info import read_camera_info_yaml

    images = _render_pngs(tmp_path, 5, seed=4)
    out = tmp_path / "cal" / "camera.yaml"
    report = tmp_path / "report"
    code = main(["calibrate", *images, "--set", "points=corners", "--set", "camera_name=cam0",
                 "--output", str(out), "--report", str(report), "--quiet"])
    assert code == 0
    assert "reprojection error" in capsys.readouterr().out
    info = read_camera_info_yaml(out)
    assert info.camera_name == "cam0" and info.distortion_model == "plumb_bob"
    assert projection_difference(Camera.preset("webcam"), info)[0] < 0.3
    summary = json.loads((report / "summary.json").read_text())
    assert summary["points"] == "corners" and len(summary["views_used"]) >= 4
    assert {"residuals.png", "coverage.png", "per_view_error.png", "verdict.png"} <= {
        p.name for p in report.glob("*.png")}
    assert (report / "report.pdf").exists()


def test_bag_topic_choice() -> None:
    from artcal_ros.cli.calibrate import _bag_topic
    from artcal_ros.core.errors import ParameterError

    one = {"/cam/image": "sensor_msgs/msg/CompressedImage", "/tf": "tf2_msgs/msg/TFMessage"}
    assert _bag_topic(one, None, "b") == "/cam/image"
    two = {"/a": "sensor_msgs/msg/Image", "/camera/image_raw": "sensor_msgs/msg/Image"}
    assert _bag_topic(two, None, "b") == "/camera/image_raw"
    with pytest.raises(ParameterError, match="several image topics"):
        _bag_topic({"/a": "sensor_msgs/msg/Image", "/b": "sensor_msgs/msg/Image"}, None, "b")
    with pytest.raises(ParameterError, match="not an image topic"):
        _bag_topic(one, "/tf", "b")
    with pytest.raises(ParameterError, match="not in b"):
        _bag_topic(one, "/nope", "b")
