"""The solve run node and CLI share: the ``calibrate.*`` parameters (names, defaults, range
checks), their way into ``calibrate()``, the solve -> write -> summary path, the node's
threaded solve, and ``artcal calibrate`` reading the same names from a file and ``--set``."""

from __future__ import annotations

import threading
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from artcal_ros.cli.main import main
from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.quality import projection_difference
from artcal_ros.core.calibrate.solve_run import (
    SolveWorker,
    calibrate_kwargs,
    run_solve,
    solve_summary,
    solve_views,
)
from artcal_ros.core.camera_info import read_camera_info_yaml
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ParameterError
from artcal_ros.core.live.coverage import ViewCollector
from artcal_ros.core.params import load_params, validate
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
from test.unit.noisy_views import noisy_views

ROOT = Path(__file__).resolve().parents[2]
PARAMS = ROOT / "config" / "calibrator.yaml"
BOARD = Board()


def square_camera() -> Camera:
    """A webcam-like lens that obeys every calibrate.* constraint: fx = fy, the principal
    point at the image centre, no tangential distortion."""
    w, h = 640, 480
    K = np.array([[600.0, 0.0, (w - 1) / 2.0], [0.0, 600.0, (h - 1) / 2.0], [0.0, 0.0, 1.0]])
    return Camera("plumb_bob", K, np.array([-0.35, 0.15, 0.0, 0.0, 0.0]), (w, h))


# --- parameters ------------------------------------------------------------------------------
def test_the_parameters_file_gives_todays_solve() -> None:
    params = load_params(PARAMS)
    assert calibrate_kwargs(params) == {
        "model": "plumb_bob", "points": "corners", "max_views": 40, "k_coefficients": 0,
        "fix_principal_point": False, "fix_aspect_ratio": False, "zero_tangent_dist": False}


@pytest.mark.parametrize(("model", "k", "allowed"), [
    ("plumb_bob", 4, "1 to 3"), ("equidistant", 5, "1 to 4"),
    ("rational_polynomial", 7, "1 to 6"), ("plumb_bob", -1, "1 to 3 (plumb_bob)")])
def test_k_coefficients_out_of_range_is_refused_naming_it(model: str, k: int,
                                                         allowed: str) -> None:
    with pytest.raises(ParameterError, match=r"parameter 'calibrate\.k_coefficients'") as e:
        load_params(PARAMS, {"camera_model": model, "calibrate.k_coefficients": k})
    assert allowed in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(("model", "k"), [("plumb_bob", 3), ("rational_polynomial", 6),
                                          ("equidistant", 4), ("equidistant", 1)])
def test_k_coefficients_in_range_is_accepted(model: str, k: int) -> None:
    params = load_params(PARAMS, {"camera_model": model, "calibrate.k_coefficients": k})
    assert calibrate_kwargs(params)["k_coefficients"] == k


def test_a_bad_flag_value_is_refused_naming_it() -> None:
    with pytest.raises(ParameterError, match=r"'calibrate\.fix_aspect_ratio'.*true or false"):
        validate({"calibrate.fix_aspect_ratio": "sometimes"})


# --- the solve run ---------------------------------------------------------------------------
def test_solve_views_applies_the_options_writes_and_summarises(tmp_path: Path) -> None:
    cam = square_camera()
    views = noisy_views(cam, 12, seed=3)
    params = load_params(PARAMS, {"calibrate.fix_aspect_ratio": True,
                                  "calibrate.zero_tangent_dist": True, "camera_name": "cam7"})
    run = solve_views(views, BOARD, cam.size, params, output=tmp_path / "c.yaml")
    info = read_camera_info_yaml(tmp_path / "c.yaml")
    assert info.camera_name == "cam7"
    K = info.camera_matrix
    assert K[0, 0] == K[1, 1] == run.result.camera_matrix[0, 0]
    assert info.dist_coeffs[2] == info.dist_coeffs[3] == 0.0
    assert projection_difference(cam, run.result)[0] < 0.06
    short = solve_summary(run)
    assert "\n" not in short and "fx = fy" in short and "p1" not in short
    assert f"wrote {tmp_path / 'c.yaml'}" in short
    long = solve_summary(run, long=True)
    assert "p1 0 (fixed)" in long and "reprojection error" in long
    assert long.splitlines()[0] == run.result.summary(long=True).splitlines()[0]


def _collected(views: list[Detections]) -> ViewCollector:
    collector = ViewCollector(BOARD)
    for v in views:
        collector.add(v)
    return collector


def test_run_solve_answers_false_with_the_reason_when_views_cannot_solve(
        tmp_path: Path) -> None:
    cam = square_camera()
    views = noisy_views(cam, 2, seed=4)
    params = load_params(PARAMS, {"output_file": str(tmp_path / "c.yaml")})
    with SolveWorker() as worker:
        outcome = run_solve(views, BOARD, cam.size, params, _collected(views).readiness(),
                            worker=worker, stopping=threading.Event())
    assert not outcome.success and outcome.result is None
    assert outcome.message.startswith("calibration failed:") and "at least 3" in outcome.message
    assert not (tmp_path / "c.yaml").exists()


def test_run_solve_gives_the_one_line_summary_and_honours_the_options(tmp_path: Path) -> None:
    cam = square_camera()
    views = noisy_views(cam, 12, seed=5)
    params = load_params(PARAMS, {"output_file": str(tmp_path / "c.yaml"),
                                  "calibrate.fix_principal_point": True})
    with SolveWorker() as worker:
        outcome = run_solve(views, BOARD, cam.size, params, _collected(views).readiness(),
                            worker=worker, stopping=threading.Event())
    assert outcome.success, outcome.message
    K = outcome.result.camera_matrix
    assert (K[0, 2], K[1, 2]) == ((cam.size[0] - 1) / 2.0, (cam.size[1] - 1) / 2.0)
    assert "cx 319.50 (fixed)" in outcome.message and "\n" not in outcome.message
    assert outcome.message.startswith(outcome.result.summary())
    assert (tmp_path / "c.yaml").exists()


def test_run_solve_ends_at_once_when_stopping(tmp_path: Path) -> None:
    cam = square_camera()
    views = noisy_views(cam, 12, seed=5)
    stopping = threading.Event()
    stopping.set()
    params = load_params(PARAMS, {"output_file": str(tmp_path / "c.yaml")})
    with SolveWorker() as worker:
        outcome = run_solve(views, BOARD, cam.size, params, _collected(views).readiness(),
                            worker=worker, stopping=stopping)
    # (the wait ends at once, or the solve has already stopped at its first stage)
    assert not outcome.success and ("shutting down" in outcome.message
                                    or "cancelled" in outcome.message), outcome.message
    assert not (tmp_path / "c.yaml").exists()


# --- the CLI reads the same names ------------------------------------------------------------
@pytest.fixture(scope="module")
def pngs(tmp_path_factory: pytest.TempPathFactory) -> list[str]:
    """Six clean renders of the square camera."""
    cam = square_camera()
    directory = tmp_path_factory.mktemp("pngs")
    rng = np.random.default_rng(8)
    paths = []
    for k, (rvec, tvec) in enumerate(random_poses(BOARD, cam, 6, rng, partial_fraction=0.2)):
        view = render_view(BOARD, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
        path = directory / f"view{k:02d}.png"
        cv2.imwrite(str(path), view.image)
        paths.append(str(path))
    return paths


def test_cli_reads_the_options_from_the_params_file_and_set(
        tmp_path: Path, pngs: list[str], capsys: pytest.CaptureFixture) -> None:
    doc = yaml.safe_load(PARAMS.read_text())
    doc["/**"]["ros__parameters"]["calibrate.fix_principal_point"] = True
    params_file = tmp_path / "params.yaml"
    params_file.write_text(yaml.safe_dump(doc))
    out = tmp_path / "camera.yaml"
    code = main(["calibrate", *pngs, "--params", str(params_file),
                 "--set", "calibrate.fix_aspect_ratio=true", "--output", str(out), "--quiet"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "fx = fy" in printed and "cx 319.50 (fixed)" in printed and f"wrote {out}" in printed
    info = read_camera_info_yaml(out)
    K = info.camera_matrix
    assert K[0, 0] == K[1, 1] and (K[0, 2], K[1, 2]) == (319.5, 239.5)
    assert projection_difference(square_camera(), info)[0] < 0.3


def test_cli_k3_is_an_alias_of_k_coefficients_3(tmp_path: Path, pngs: list[str],
                                                capsys: pytest.CaptureFixture) -> None:
    alias, named = tmp_path / "alias.yaml", tmp_path / "named.yaml"
    assert main(["calibrate", *pngs[:4], "--k3", "--output", str(alias), "--quiet"]) == 0
    assert "deprecated" in capsys.readouterr().err
    assert main(["calibrate", *pngs[:4], "--set", "calibrate.k_coefficients=3",
                 "--output", str(named), "--quiet"]) == 0
    a, b = read_camera_info_yaml(alias), read_camera_info_yaml(named)
    assert a.dist_coeffs[4] != 0.0
    assert np.array_equal(a.camera_matrix, b.camera_matrix)
    assert np.array_equal(a.dist_coeffs, b.dist_coeffs)


@pytest.mark.parametrize("extra", [["--set", "camera_model=equidistant"],
                                   ["--set", "calibrate.k_coefficients=1"]])
def test_cli_k3_with_another_model_or_count_exits_2(tmp_path: Path, pngs: list[str],
                                                   extra: list[str],
                                                   capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "c.yaml"
    assert main(["calibrate", *pngs[:3], "--k3", *extra, "--output", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--k3" in err and "Traceback" not in err and not out.exists()


def test_cli_out_of_range_k_coefficients_exits_2_naming_it(tmp_path: Path, pngs: list[str],
                                                          capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "c.yaml"
    assert main(["calibrate", *pngs[:3], "--set", "calibrate.k_coefficients=4",
                 "--output", str(out)]) == 2
    assert "calibrate.k_coefficients" in capsys.readouterr().err and not out.exists()
