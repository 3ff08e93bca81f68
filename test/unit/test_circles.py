"""Circle grids (circles, acircles): geometry against OpenCV's conventions, parameters, the
printable board, and detection against the renderer's exact truth."""

from __future__ import annotations

import json
import zlib
from functools import cache
from pathlib import Path

import cv2
import numpy as np
import pytest

from artcal_ros import Board
from artcal_ros.cli.main import main as artcal
from artcal_ros.core.board.printable import (
    board_to_png_px,
    layout_page,
    render_pdf,
    render_png,
    render_svg,
)
from artcal_ros.core.detect import Detector
from artcal_ros.core.detect.circle_grid import find_circle_grid, orient_grid
from artcal_ros.core.detect.image import to_gray8
from artcal_ros.core.errors import BoardError, ParameterError
from artcal_ros.core.params import validate
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.photometry import Photometry
from artcal_ros.synth.poses import random_poses
from artcal_ros.synth.view import RenderedView, render_view

CIRCLES = Board(board_type="circles", cols=7, rows=5, square_length=0.04)
ACIRCLES = Board(board_type="acircles", cols=4, rows=11, square_length=0.03)


@cache
def _views(board: Board, n: int, seed: int, partial: float = 0.0) -> tuple[RenderedView, ...]:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(seed)
    return tuple(render_view(board, cam, r, t, photometry=Photometry.clean(), rng=rng)
                 for r, t in random_poses(board, cam, n, rng, partial_fraction=partial))


# --- geometry ---------------------------------------------------------------------------
def test_object_points_follow_opencvs_calibration_sample() -> None:
    s = 0.03
    sym = Board(board_type="circles", cols=4, rows=3, square_length=s).object_points()
    asym = Board(board_type="acircles", cols=4, rows=3, square_length=s).object_points()
    want_sym, want_asym = [], []
    for i in range(3):                      # as OpenCV's samples/cpp/calibration.cpp
        for j in range(4):
            want_sym.append((j * s, i * s, 0.0))
            want_asym.append(((2 * j + i % 2) * s, i * s, 0.0))
    np.testing.assert_allclose(sym, want_sym, atol=1e-12)
    np.testing.assert_allclose(asym, want_asym, atol=1e-12)
    # black circles of 0.4 spacings' diameter on white
    b = ACIRCLES
    p = b.object_points()[5]
    assert not b.is_white(np.array([p[0] + 0.19 * s]), np.array([p[1]]))[0]
    assert b.is_white(np.array([p[0] + 0.21 * s]), np.array([p[1]]))[0]
    assert b.is_white(np.array([p[0] + s]), np.array([p[1]]))[0]        # the empty cell
    assert b.has_points and b.n_markers == 0 and len(b.point_ids) == 44
    r = 0.2 * s
    np.testing.assert_allclose(b.extent_m, (-r, -r, 7 * s + r, 10 * s + r))


def test_opencv_finds_the_grid_of_our_render_in_the_documented_order() -> None:
    for board in (CIRCLES, ACIRCLES):
        view = _views(board, 6, 71)[0]
        grid = find_circle_grid(to_gray8(view.image), board)
        assert grid is not None
        oriented = orient_grid(grid, board)
        assert oriented is not None
        err = np.linalg.norm(oriented[0].reshape(-1, 2) - view.points_px, axis=1)
        assert err.max() < 1.5, board.board_type     # blob centres, in the board's order
        if board is ACIRCLES:       # no symmetry: our ids are OpenCV's own order
            assert np.array_equal(oriented[0], grid)


# --- parameters -------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["circles", "acircles"])
@pytest.mark.parametrize(("values", "name"), [
    ({"board.cols": 1}, "board.cols"),
    ({"board.rows": 1}, "board.rows"),
    ({"board.square_length": 0.0}, "board.square_length"),
    ({"board.square_length": -0.02}, "board.square_length"),
])
def test_bad_circle_parameters_are_refused_naming_them(kind: str, values: dict[str, object],
                                                       name: str) -> None:
    params = {"board.type": kind, "board.cols": 4, "board.rows": 5,
              "board.square_length": 0.02, **values}
    with pytest.raises(ParameterError, match=name.replace(".", r"\.")):
        validate(params)
    with pytest.raises(BoardError, match=name.replace(".", r"\.")):
        Board.from_params(params)


def test_circle_board_parameters_round_trip_and_ignore_marker_sizes() -> None:
    # the marker sizes of a parameters file do not limit a circle grid (0.06 m > spacing)
    params = {"board.type": "acircles", "board.cols": 4, "board.rows": 11,
              "board.square_length": 0.02, "board.marker_length": 0.06}
    validate(params)
    board = Board.from_params(params)
    assert Board.from_params(board.to_params()) == board
    assert "diameter 8 mm" in board.describe()


# --- printable board --------------------------------------------------------------------
@pytest.mark.parametrize("board", [Board(board_type="circles", cols=4, rows=3,
                                         square_length=0.02),
                                   Board(board_type="acircles", cols=3, rows=4,
                                         square_length=0.02)])
def test_printed_circles_sit_at_their_object_points_at_exact_scale(board: Board,
                                                                   tmp_path: Path) -> None:
    dpi = 200.0
    layout = layout_page(board)
    png = tmp_path / "b.png"
    png.write_bytes(render_png(layout, dpi))
    img = cv2.imread(str(png), cv2.IMREAD_GRAYSCALE)
    want = board_to_png_px(layout, board.object_points(), dpi)
    r_px = board.circles.radius * 1000 * dpi / 25.4 if board.circles else 0.0
    for (x, y) in want:
        x0, y0 = int(x - 2 * r_px), int(y - 2 * r_px)
        patch = 1.0 - img[y0:int(y + 2 * r_px) + 1, x0:int(x + 2 * r_px) + 1] / 255.0
        yy, xx = np.mgrid[0:patch.shape[0], 0:patch.shape[1]]
        area = patch.sum()
        centre = np.array([(patch * xx).sum(), (patch * yy).sum()]) / area + [x0, y0]
        np.testing.assert_allclose(centre, (x, y), atol=0.02)          # px at 200 dpi
        assert area == pytest.approx(np.pi * r_px ** 2, rel=0.01)       # 8 mm discs
    assert len(layout.discs_mm) == len(board.point_ids)
    np.testing.assert_allclose(layout.discs_mm[:, 2], 4.0)      # 8 mm circles
    # the vector formats draw the same discs: SVG circles, PDF closed Bezier paths
    svg = render_svg(layout)
    for x, y, r in layout.discs_mm:
        assert f'<circle cx="{x:.4f}" cy="{y:.4f}" r="{r:.4f}"' in svg
    pdf = zlib.decompress(render_pdf(layout).split(b"stream\n")[1].split(b"\nendstream")[0])
    assert pdf.count(b" c h") == len(board.point_ids)


# --- detection --------------------------------------------------------------------------
@pytest.mark.parametrize("board", [CIRCLES, ACIRCLES])
def test_circle_centres_against_truth(board: Board) -> None:
    detector = Detector(board)
    errors, found = [], 0
    for view in _views(board, 6, 71):
        dets = detector.detect(view.image)
        if not len(dets.point_ids):
            continue
        found += 1
        truth = view.points_px
        # ids are the print's up to its symmetry (test_turned_prints_... checks which)
        err = min((np.linalg.norm(dets.points_px - truth[s[dets.point_ids]], axis=1)
                   for s in _symmetries(board)), key=lambda e: float(e.max()))
        assert err.max() < 0.1
        assert len(dets.point_ids) >= len(board.point_ids) - 2
        errors.append(err)
    assert found >= 3
    rms = float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))
    assert rms < 0.03          # measured 0.014 (circles) and 0.017 px (acircles)


def test_perspective_correction_beats_the_ellipse_centre() -> None:
    # a steep view of large circles: the ellipse's centre is off by more than our centre
    from artcal_ros.core.detect.circles import measure_circle
    from artcal_ros.core.detect.image import linearise

    board, errs_ours, errs_ellipse = CIRCLES, [], []
    for view in _views(board, 6, 71):
        dets = Detector(board).detect(view.image)
        if not len(dets.point_ids):
            continue
        grid = orient_grid(find_circle_grid(to_gray8(view.image), board), board)
        assert grid is not None
        lin = linearise(view.image, 2.2).astype(np.float32)
        for k, p in zip(dets.point_ids, dets.points_px, strict=True):
            C, _, _ = measure_circle(lin, grid[0].reshape(-1, 2)[k], grid[1],
                                     board.object_points()[k, :2], 0.2 * board.square_length)
            c = np.linalg.solve(C, [0.0, 0.0, 1.0])
            errs_ellipse.append(np.linalg.norm(c[:2] / c[2] - view.points_px[k]))
            errs_ours.append(np.linalg.norm(p - view.points_px[k]))
    ours = np.sqrt(np.mean(np.square(errs_ours)))
    ellipse = np.sqrt(np.mean(np.square(errs_ellipse)))
    assert ours < 0.5 * ellipse      # measured 0.014 vs 0.088 px


def test_partial_circle_grids_give_no_points() -> None:
    for board in (CIRCLES, ACIRCLES):
        detector = Detector(board)
        partial = [v for v in _views(board, 8, 73, partial=1.0) if not v.points_inside.all()]
        assert partial
        for view in partial:
            assert len(detector.detect(view.image).point_ids) == 0


@pytest.mark.parametrize(("printed", "configured"), [
    (CIRCLES, Board(board_type="circles", cols=6, rows=5, square_length=0.04)),
    (CIRCLES, Board(board_type="circles", cols=7, rows=4, square_length=0.04)),
    (ACIRCLES, Board(board_type="acircles", cols=4, rows=10, square_length=0.03)),
    (ACIRCLES, Board(board_type="acircles", cols=3, rows=11, square_length=0.03)),
])
def test_a_larger_print_than_configured_gives_no_ids(printed: Board, configured: Board) -> None:
    # OpenCV finds the configured grid inside the larger print; counted from its edge every
    # id would be wrong, so the view must give nothing
    detector = Detector(configured)
    for view in _views(printed, 4, 71):
        assert len(detector.detect(view.image).point_ids) == 0


def test_detect_json_lists_circle_points(tmp_path: Path) -> None:
    view = _views(ACIRCLES, 6, 71)[0]
    cv2.imwrite(str(tmp_path / "a.png"), view.image)
    params = tmp_path / "p.yaml"
    params.write_text("/**:\n  ros__parameters:\n    board.type: acircles\n    board.cols: 4\n"
                      "    board.rows: 11\n    board.square_length: 0.03\n")
    out = tmp_path / "d.json"
    assert artcal(["detect", str(tmp_path / "a.png"), "--params", str(params),
                   "--json", str(out)]) == 0
    image = json.loads(out.read_text())["images"][0]
    assert image["markers"] == []
    ids = [p["id"] for p in image["points"]]
    assert ids == sorted(ids) and len(ids) >= 42
    xy = np.array([p["xy"] for p in image["points"]])
    assert np.abs(xy - view.points_px[ids]).max() < 0.1


def _symmetries(board: Board) -> list[np.ndarray]:
    """Id permutations under which the print maps onto itself by a turn in its plane."""
    obj = board.object_points()[:, :2]
    c = obj.mean(axis=0)
    out = []
    for k in range(4):
        a = k * np.pi / 2
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        moved = (obj - c) @ R.T + c
        d = np.linalg.norm(moved[:, None] - obj[None], axis=2)
        if np.all(d.min(axis=1) < 1e-9):
            out.append(d.argmin(axis=1))
    return out


@pytest.mark.parametrize(("board", "n_symmetries"), [
    (CIRCLES, 2),          # a half turn
    (ACIRCLES, 1),         # 11 rows: none, every id is exact
    (Board(board_type="acircles", cols=4, rows=10, square_length=0.03), 2),
    (Board(board_type="circles", cols=5, rows=5, square_length=0.04), 4)],
    ids=["circles", "acircles", "acircles_even_rows", "square"])
def test_turned_prints_are_numbered_by_the_half_turn_rule(board: Board,
                                                          n_symmetries: int) -> None:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(75)
    rvec, tvec = random_poses(board, cam, 1, rng, partial_fraction=0.0)[0]
    R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))[0]
    x0, y0, x1, y1 = board.extent_m
    c = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    syms = _symmetries(board)
    assert len(syms) == n_symmetries
    detector = Detector(board)
    found = 0
    for k in range(4):      # the print turned in its plane about its centre
        a = k * np.pi / 2
        Rz = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        R2 = R @ Rz
        t2 = R @ (c - Rz @ c) + np.asarray(tvec, dtype=np.float64).reshape(3)
        view = render_view(board, cam, cv2.Rodrigues(R2)[0].ravel(), t2,
                           photometry=Photometry.clean(), rng=rng)
        dets = detector.detect(view.image)
        if not len(dets.point_ids):
            continue
        # the ids are the print's up to one of its symmetries ...
        errs = [np.linalg.norm(dets.points_px - view.points_px[s[dets.point_ids]], axis=1)
                for s in syms]
        best = int(np.argmin([e.max() for e in errs]))
        assert errs[best].max() < 0.1
        # ... the one whose point 0 is nearest the image's top-left
        zero = [view.points_px[s[0]].sum() for s in syms]
        assert best == int(np.argmin(zero))
        found += 1
    assert found >= 2


def test_rendered_circles_have_their_true_area_and_centre() -> None:
    # straight on through a lens without distortion, a circle's image is a circle about the
    # image of its centre: the renderer's coverage must have that centroid and area
    from artcal_ros.synth.render import board_coverage

    web = Camera.preset("webcam")
    cam = Camera(web.model, web.K, np.zeros_like(web.dist), web.size)
    board = Board(board_type="acircles", cols=3, rows=4, square_length=0.03)
    rvec, tvec = np.array([0.0, 0.0, 0.1]), np.array([-0.06, -0.05, 0.6])
    ink = 1.0 - board_coverage(board, cam, rvec, tvec).white
    centres = cam.project(board.object_points(), rvec, tvec)
    r_px = cam.K[0, 0] * board.circles.radius / 0.6 if board.circles else 0.0
    yy, xx = np.mgrid[0:ink.shape[0], 0:ink.shape[1]]
    for x, y in centres:
        near = np.hypot(xx - x, yy - y) < r_px + 2
        w = ink[near]
        np.testing.assert_allclose([np.sum(w * xx[near]) / w.sum(),
                                    np.sum(w * yy[near]) / w.sum()], (x, y), atol=2e-3)
        # an ellipse of semi-axes fx r / z and fy r / z
        assert w.sum() == pytest.approx(np.pi * r_px ** 2 * cam.K[1, 1] / cam.K[0, 0],
                                        rel=5e-4)


def test_a_known_camera_straightens_the_edges_instead_of_the_fitted_lens() -> None:
    cam = Camera.preset("webcam")
    errors = []
    for view in _views(CIRCLES, 6, 71)[:3]:
        dets = Detector(CIRCLES).detect(view.image, cam)
        if len(dets.point_ids):
            errors.append(np.linalg.norm(dets.points_px - view.points_px[dets.point_ids],
                                         axis=1))
    assert errors
    assert np.sqrt(np.mean(np.concatenate(errors) ** 2)) < 0.03
