"""The renderer's truth is exact: projection, inversion, edge positions, photometry, files."""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pytest

from artcal_ros.cli import synth as synth_cmd
from artcal_ros.core.board import Board
from artcal_ros.core.errors import ArtcalError, ParameterError
from artcal_ros.synth import (
    PRESETS,
    Camera,
    Photometry,
    load_truth,
    marker_truth,
    project_points,
    random_poses,
    rays_from_pixels,
    render_linear,
    render_view,
)
from artcal_ros.synth.dataset import motion_blur_from_poses, write_dataset
from artcal_ros.synth.photometry import sense_and_encode

RATIONAL = Camera("rational_polynomial",
                  np.array([[650.0, 0, 330.5], [0, 648.0, 241.2], [0, 0, 1]]),
                  np.array([-0.2, 0.05, 0.001, -0.0007, 0.01, 0.15, -0.03, 0.02]), (640, 480))


def _camera(name: str) -> Camera:
    return RATIONAL if name == "rational" else Camera.preset(name)


def _opencv_project(cam: Camera, pts: np.ndarray, rvec: np.ndarray,
                    tvec: np.ndarray) -> np.ndarray:
    if cam.model == "equidistant":
        out = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), rvec, tvec, cam.K, cam.dist)[0]
    else:
        out = cv2.projectPoints(pts, rvec, tvec, cam.K, cam.dist)[0]
    return np.asarray(out).reshape(-1, 2)


@pytest.mark.parametrize("name", [*PRESETS, "rational"])
def test_project_points_agrees_with_opencv(name: str) -> None:
    cam = _camera(name)
    rng = np.random.default_rng(7)
    # points across the whole field of view, 0.3 - 3 m away, in the board frame of a pose
    rvec, tvec = np.array([0.2, -0.15, 0.1]), np.array([-0.1, 0.05, 0.2])
    pts_cam = rng.uniform([-1.0, -0.8, 0.3], [1.0, 0.8, 3.0], size=(3000, 3))
    R = cv2.Rodrigues(rvec)[0]
    pts_board = (pts_cam - tvec) @ R          # R^T (p - t)
    mine = project_points(cam, pts_board, rvec, tvec)
    ref = _opencv_project(cam, pts_board, rvec, tvec)
    assert np.all(np.isfinite(mine))
    assert np.max(np.abs(mine - ref)) < 1e-6
    # camera-frame input gives the same points
    assert np.max(np.abs(project_points(cam, pts_cam) - mine)) < 1e-9


@pytest.mark.parametrize("name", [*PRESETS, "rational"])
def test_pixel_rays_invert_the_forward_model(name: str) -> None:
    cam = _camera(name)
    w, h = cam.size
    u, v = np.meshgrid(np.linspace(0, w - 1, 61), np.linspace(0, h - 1, 47))
    ray, ray_du, ray_dv, valid = rays_from_pixels(cam, u.ravel(), v.ravel())
    assert valid.all(), "every preset pixel must see a ray (no fold of the lens polynomial)"
    front = ray[:, 2] > 0   # fisheye corners look more than 90 degrees off axis
    back = project_points(cam, ray[front])
    pix = np.stack([u.ravel(), v.ravel()], axis=-1)[front]
    assert np.max(np.abs(back - pix)) < 1e-7
    # the derivatives match finite differences of the inverse
    du = (rays_from_pixels(cam, u.ravel() + 1e-4, v.ravel())[0]
          - rays_from_pixels(cam, u.ravel() - 1e-4, v.ravel())[0]) / 2e-4
    dv = (rays_from_pixels(cam, u.ravel(), v.ravel() + 1e-4)[0]
          - rays_from_pixels(cam, u.ravel(), v.ravel() - 1e-4)[0]) / 2e-4
    assert np.max(np.abs(du - ray_du)) < 1e-8
    assert np.max(np.abs(dv - ray_dv)) < 1e-8


def _edge_rows(cam: Camera, board: Board, rvec: np.ndarray, tvec: np.ndarray,
               x_board: float) -> tuple[np.ndarray, np.ndarray]:
    """The true image of the board line x = x_board along a marker's side, as a curve."""
    ys = np.linspace(0.0, board.marker_length, 4000)
    px = project_points(cam, np.stack([np.full_like(ys, x_board), ys, 0 * ys], -1), rvec, tvec)
    order = np.argsort(px[:, 1])
    return px[order, 1], px[order, 0]


EDGE_CASES = [("webcam", np.array([0.25, -0.3, 0.06]), np.array([-0.1, -0.06, 0.40])),
              ("fisheye", np.array([-0.2, 0.35, -0.1]), np.array([-0.08, -0.05, 0.30])),
              ("rational", np.array([0.3, 0.25, -0.2]), np.array([-0.12, -0.02, 0.42]))]


@pytest.mark.parametrize(("name", "rvec", "tvec"), EDGE_CASES)
def test_rendered_edge_lies_where_the_truth_says(name: str, rvec: np.ndarray,
                                                 tvec: np.ndarray) -> None:
    """A tilted, distorted marker side: white gap on its left, black border on its right.

    In linear, noise-free output each pixel is its white area fraction, so along a row
    the edge sits at (first pixel's left side) + (sum of the values): this is the 50 %
    crossing of the pixel-integrated edge, exact for any position of the edge."""
    board = Board(cols=3, rows=2)
    cam = _camera(name)
    img = render_linear(board, cam, rvec, tvec, photometry=Photometry.exact())
    py, px = _edge_rows(cam, board, rvec, tvec, board.pitch)   # left side of marker 1
    errors = []
    for row in range(int(np.ceil(py.min())) + 3, int(py.max()) - 3):
        x_true = float(np.interp(row, py, px))
        a, b = round(x_true) - 6, round(x_true) + 4
        seg = img[row, a:b + 1]
        assert seg[0] > 1 - 1e-9 and seg[-1] < 1e-9, "the window must span the whole edge"
        errors.append(a - 0.5 + seg.sum() - x_true)
    assert len(errors) > 40
    assert np.max(np.abs(errors)) < 0.01
    assert np.max(np.abs(errors)) < 0.002   # in fact


def test_render_matches_brute_force_point_sampling() -> None:
    """Corners included: each pixel equals the mean of 32 x 32 exact point samples (their own
    sampling error is up to ~1/32 where an edge crosses the pixel)."""
    board = Board()
    cam = Camera.preset("webcam")
    rvec, tvec = np.array([0.3, -0.35, 0.2]), np.array([-0.3, -0.15, 0.5])
    img = render_linear(board, cam, rvec, tvec, photometry=Photometry.exact())
    y0, x0, h, w, s = 200, 280, 24, 30, 32
    off = (np.arange(s) + 0.5) / s - 0.5
    uu = np.broadcast_to(np.arange(x0, x0 + w)[None, :, None, None] + off, (h, w, s, s))
    vv = np.broadcast_to(np.arange(y0, y0 + h)[:, None, None, None] + off[:, None], (h, w, s, s))
    ray = rays_from_pixels(cam, uu.ravel(), vv.ravel())[0]
    R = cv2.Rodrigues(rvec)[0]
    points = (ray * ((R[:, 2] @ tvec) / (ray @ R[:, 2]))[:, None] - tvec) @ R   # on the board
    ref = board.is_white(points[:, 0], points[:, 1]).reshape(h, w, s * s).mean(axis=-1)
    diff = np.abs(img[y0:y0 + h, x0:x0 + w] - ref)
    assert 0.1 < ref.mean() < 0.9, "the window must hold edges and corners"
    assert diff.max() < 0.03
    assert diff.mean() < 1e-3


def test_blurred_edge_50_percent_crossing() -> None:
    """With defocus the interpolated 50 % crossing of linear output is still on the edge."""
    name, rvec, tvec = EDGE_CASES[0]
    board = Board(cols=3, rows=2)
    cam = Camera.preset(name)
    img = render_linear(board, cam, rvec, tvec,
                        photometry=Photometry.exact().with_(defocus_px=2.5))
    py, px = _edge_rows(cam, board, rvec, tvec, board.pitch)
    errors = []
    for row in range(int(np.ceil(py.min())) + 4, int(py.max()) - 4):
        x_true = float(np.interp(row, py, px))
        i = int(np.flatnonzero((img[row, :-1] >= 0.5) & (img[row, 1:] < 0.5)
                               & (np.abs(np.arange(img.shape[1] - 1) - x_true) < 2))[0])
        # cubic through the 4 samples around the crossing, root in [i, i + 1]
        coeffs = np.polyfit(np.arange(-1, 3), img[row, i - 1:i + 3] - 0.5, 3)
        roots = [r.real for r in np.roots(coeffs) if abs(r.imag) < 1e-12 and 0 <= r.real <= 1]
        errors.append(i + roots[0] - x_true)
    assert len(errors) > 40
    assert np.max(np.abs(errors)) < 0.01


def test_photometry_noise_saturation_gamma() -> None:
    rng = np.random.default_rng(3)
    flat = np.full((256, 256), 0.5)
    # shot + read noise: std = sqrt(signal_e + read^2) / full_well
    phot = Photometry(gamma=1.0, full_well=1000.0, read_noise=5.0)
    img = sense_and_encode(flat, phot, rng, "mono16").astype(np.float64) / 65535.0
    expected = np.sqrt(500.0 + 25.0) / 1000.0
    assert abs(img.std() / expected - 1.0) < 0.03
    assert abs(img.mean() - 0.5) < 0.001
    quiet = sense_and_encode(flat, phot.with_(full_well=50000.0, read_noise=1.0), rng, "mono16")
    assert quiet.astype(np.float64).std() < img.std() * 65535.0 / 5
    # exposure beyond full scale clips (saturation)
    hot = sense_and_encode(flat, phot.with_(exposure=2.5), rng, "mono8")
    assert (hot == 255).mean() > 0.99
    # gamma encoding: noise-free 0.5 of full scale -> 255 * 0.5 ** (1 / 2.2)
    enc = sense_and_encode(flat, Photometry(noise=False, gamma=2.2), rng, "mono8")
    assert np.all(enc == round(255 * 0.5 ** (1 / 2.2)))
    lin = sense_and_encode(flat, Photometry(noise=False, gamma=1.0), rng, "mono8")
    assert np.all(lin == 128)


def test_photometry_in_a_render() -> None:
    board = Board()
    cam = Camera.preset("webcam")
    rvec, tvec = np.array([0.1, 0.2, 0.0]), np.array([-0.75, -0.35, 1.5])
    exact = render_linear(board, cam, rvec, tvec, photometry=Photometry.exact())
    # defocus keeps the mean (energy) and widens edges
    blurred = render_linear(board, cam, rvec, tvec,
                            photometry=Photometry.exact().with_(defocus_px=2.0))
    grad_sharp = np.abs(np.diff(exact, axis=1)).max()
    grad_blur = np.abs(np.diff(blurred, axis=1)).max()
    assert grad_blur < 0.6 * grad_sharp
    inner = (slice(20, -20), slice(20, -20))
    assert abs(blurred[inner].mean() - exact[inner].mean()) < 0.01
    # vignetting darkens the corners relative to the centre by its strength
    flat_board = Photometry.exact().with_(vignetting=0.4)
    vig = render_linear(board, cam, rvec, tvec, photometry=flat_board)
    ratio = vig / np.where(exact > 0.5, exact, np.nan)
    assert abs(np.nanmax(ratio) - 1.0) < 0.01
    assert np.nanmin(ratio) < 0.75
    # colour encodings come back BGR; mono16 uses the full range
    view = render_view(board, cam, rvec, tvec, encoding="bgr8")
    assert view.image.shape == (480, 640, 3) and view.image.dtype == np.uint8
    deep = render_view(board, cam, rvec, tvec, encoding="mono16")
    assert deep.image.dtype == np.uint16 and deep.image.max() > 40000
    jpeg = render_view(board, cam, rvec, tvec, photometry=Photometry.harsh())
    assert jpeg.image.dtype == np.uint8


def test_inside_markers_are_drawn_and_partial_views_flag_the_rest() -> None:
    board = Board()
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(11)
    poses = random_poses(board, cam, 3, rng, partial_fraction=1.0)
    for rvec, tvec in poses:
        corners, _, inside, side = marker_truth(board, cam, rvec, tvec)
        assert inside.sum() >= 8 and not inside.all()
        w, h = cam.size
        c = corners[inside]
        assert np.all((c >= 0) & (c <= [w - 1, h - 1]))
        out = corners[~inside]
        off = ~np.all((out >= 0) & (out <= [w - 1, h - 1]), axis=(1, 2))
        assert np.all(off | np.any(np.isnan(out), axis=(1, 2)))
        # the render agrees: the middle of each inside marker's top border is black ink and
        # the middle of the gap to its left is white paper
        img = render_linear(board, cam, rvec, tvec, photometry=Photometry.exact())
        ids = board.ids[inside & (side > 30)]
        assert len(ids) >= 4
        tl = board.object_corners(ids)[:, 0]
        ink = tl + np.array([0.5 * board.marker_length, 0.5 * board.module_length, 0])
        paper = tl + np.array([-0.5 * board.marker_separation, 0.5 * board.marker_length, 0])
        for pts, want_white in ((ink, False), (paper, True)):
            px = np.round(project_points(cam, pts, rvec, tvec)).astype(int)
            seen = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
            values = img[px[seen, 1], px[seen, 0]]
            assert np.all(values > 0.99) if want_white else np.all(values < 0.01)


def test_random_views_calibrate_well() -> None:
    """20 random views with 0.1 px noise on the true corners pin the intrinsics down."""
    board = Board()
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(5)
    obj, img = [], []
    for rvec, tvec in random_poses(board, cam, 20, rng, partial_fraction=0.3):
        corners, _, inside, _ = marker_truth(board, cam, rvec, tvec)
        obj.append(board.object_corners(board.ids[inside]).reshape(-1, 3).astype(np.float32))
        noisy = corners[inside].reshape(-1, 2) + rng.normal(0, 0.1, (inside.sum() * 4, 2))
        img.append(noisy.astype(np.float32))
    rms, K, dist, _, _ = cv2.calibrateCamera(obj, img, cam.size, None, None)
    assert rms < 0.2
    assert abs(K[0, 0] - cam.K[0, 0]) < 1.0 and abs(K[1, 1] - cam.K[1, 1]) < 1.0
    assert abs(K[0, 2] - cam.K[0, 2]) < 1.0 and abs(K[1, 2] - cam.K[1, 2]) < 1.0
    assert abs(dist.ravel()[0] - cam.dist[0]) < 0.01


def _run_cli(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    synth_cmd.add_arguments(parser)
    return synth_cmd.run(parser.parse_args(argv))


def test_cli_writes_pngs_and_truth(tmp_path: Path, params_file: Path) -> None:
    out = tmp_path / "frames"
    assert _run_cli(["--params", str(params_file), "--camera", "webcam", "--frames", "3",
                     "--out", str(out), "--seed", "4"]) == 0
    files = sorted(p.name for p in out.glob("frame_*.png"))
    assert files == ["frame_0000.png", "frame_0001.png", "frame_0002.png"]
    truth = load_truth(out / "truth.json")
    assert truth.camera.model == "plumb_bob" and truth.camera.size == (640, 480)
    assert np.allclose(truth.camera.K, Camera.preset("webcam").K)
    assert truth.board == Board()
    assert len(truth.frames) == 3 and truth.seed == 4
    for f in truth.frames:
        image = cv2.imread(str(out / f.file), cv2.IMREAD_UNCHANGED)
        assert image.shape == (480, 640) and image.dtype == np.uint8
        corners, centers, inside, _ = marker_truth(truth.board, truth.camera, f.rvec, f.tvec)
        k = f.ids - truth.board.first_id
        assert np.max(np.abs(f.corners_px - corners[k])) < 1e-6
        assert np.max(np.abs(f.centers_px - centers[k])) < 1e-6
        assert np.array_equal(f.inside, inside[k])
    assert truth.by_file("frame_0001.png") is truth.frames[1]
    perfect = truth.frames[0].true_detections(truth.camera.size)
    assert len(perfect) == int(truth.frames[0].inside.sum()) >= 8
    assert perfect.image_size == (640, 480)
    # the same seed renders the same images
    again = tmp_path / "again"
    _run_cli(["--frames", "3", "--out", str(again), "--seed", "4"])
    for name in files:
        assert np.array_equal(cv2.imread(str(again / name)), cv2.imread(str(out / name)))


def test_cli_camera_from_a_camera_info_file(tmp_path: Path) -> None:
    yaml_file = tmp_path / "cam.yaml"
    yaml_file.write_text(
        "image_width: 320\nimage_height: 240\ncamera_name: test\n"
        "camera_matrix: {rows: 3, cols: 3, data: [300, 0, 161, 0, 301, 119, 0, 0, 1]}\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients: {rows: 1, cols: 5, data: [-0.2, 0.05, 0, 0, 0]}\n")
    out = tmp_path / "frames"
    assert _run_cli(["--camera", str(yaml_file), "--frames", "1", "--out", str(out)]) == 0
    truth = load_truth(out / "truth.json")
    assert truth.camera.size == (320, 240) and truth.camera.K[0, 0] == 300.0
    assert np.allclose(truth.camera.dist, [-0.2, 0.05, 0, 0, 0])
    assert cv2.imread(str(out / "frame_0000.png")).shape[:2] == (240, 320)


def test_motion_blur_follows_the_camera() -> None:
    """The camera slides 1 cm per frame along the board's x at 1 m: the board's image moves
    6 px per frame the other way; a shutter open for half the frame smears it 3 px."""
    cam = Camera("plumb_bob", np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]]),
                 np.zeros(5), (640, 480))
    poses = [(np.zeros(3), np.array([-0.75 - 0.01 * k, -0.35, 1.0])) for k in range(3)]
    length, angle = motion_blur_from_poses(Board(), cam, poses, 1, 0.5)
    assert abs(length - 3.0) < 1e-9 and abs(abs(angle) - 180.0) < 1e-6


def test_write_dataset_is_library_code(tmp_path: Path) -> None:
    """Called directly (as the benchmarks do): reports each frame, returns the truth's path."""
    done: list[None] = []
    truth_path = write_dataset(Board(), Camera.preset("webcam"), tmp_path / "d", frames=2,
                               seed=3, progress=lambda: done.append(None))
    assert truth_path == tmp_path / "d" / "truth.json" and len(done) == 2
    assert [f.file for f in load_truth(truth_path).frames] == ["frame_0000.png",
                                                               "frame_0001.png"]
    with pytest.raises(ParameterError, match="frames"):
        write_dataset(Board(), Camera.preset("webcam"), tmp_path / "e", frames=0)


def test_cli_refuses_bad_input(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match="preset"):
        _run_cli(["--camera", "nope", "--frames", "1", "--out", str(tmp_path / "x")])
    with pytest.raises(ParameterError, match="encoding"):
        _run_cli(["--encoding", "yuv9", "--frames", "1", "--out", str(tmp_path / "x")])
    with pytest.raises(ParameterError, match="shutter"):
        _run_cli(["--shutter", "0.5", "--rate", "10", "--frames", "1", "--out",
                  str(tmp_path / "x")])
    with pytest.raises(ParameterError, match="photometry"):
        _run_cli(["--photometry", "dim", "--frames", "1", "--out", str(tmp_path / "x")])
    (tmp_path / "bad.json").write_text("{}")
    with pytest.raises(ArtcalError, match="truth"):
        load_truth(tmp_path / "bad.json")


def test_cli_writes_a_bag_with_truth_beside_it(tmp_path: Path) -> None:
    from artcal_ros.bag import BagReader
    from artcal_ros.core.images import image_to_numpy
    out = tmp_path / "run"
    assert _run_cli(["--frames", "3", "--out", str(out), "--bag", "--encoding", "rgb8",
                     "--motion", "smooth", "--rate", "5", "--seed", "2"]) == 0
    assert (out / "metadata.yaml").is_file() and (out / "truth.json").is_file()
    truth = load_truth(out / "truth.json")
    with BagReader(out) as reader:
        assert reader.topics == {"/camera/image_raw": "sensor_msgs/msg/Image"}
        messages = list(reader.messages())
    assert [m.log_time_ns for m in messages] == [f.stamp_ns for f in truth.frames]
    assert messages[1].log_time_ns - messages[0].log_time_ns == 200_000_000
    msg = messages[0].decode()
    assert (msg.encoding, msg.width, msg.height) == ("rgb8", 640, 480)
    assert image_to_numpy(msg).shape == (480, 640, 3)
    with pytest.raises(ArtcalError, match="exists"):   # never overwrites a bag unasked
        _run_cli(["--frames", "1", "--out", str(out), "--bag"])


def test_committed_sample_bag_matches_its_truth() -> None:
    from artcal_ros.bag import BagReader
    root = Path(__file__).resolve().parents[2] / "bags" / "sample"
    truth = load_truth(root / "truth.json")
    assert truth.camera.size == (640, 480) and truth.board == Board()
    with BagReader(root) as reader:
        stamps = [m.log_time_ns for m in reader.messages(topics=["/camera/image_raw"])]
    assert len(stamps) == len(truth.frames) >= 50
    assert stamps == [f.stamp_ns for f in truth.frames]
    for f in truth.frames[::10]:
        corners, _, inside, _ = marker_truth(truth.board, truth.camera, f.rvec, f.tvec)
        k = f.ids - truth.board.first_id
        assert np.max(np.abs(f.corners_px - corners[k])) < 1e-6
        assert inside.sum() >= 8


def test_artcal_cli_exit_status(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Through the real ``artcal`` entry point: success 0, a bad preset 2 with one line."""
    for verb in ("board", "synth", "detect", "calibrate"):
        pytest.importorskip(f"artcal_ros.cli.{verb}")
    from artcal_ros.cli.main import main
    assert main(["synth", "--camera", "nope", "--frames", "1", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "preset" in err[0] and "webcam" in err[0]
    assert main(["synth", "--frames", "1", "--out", str(tmp_path / "ok")]) == 0
    assert (tmp_path / "ok" / "frame_0000.png").is_file()


def test_poses_held_across_the_image_reach_its_sides() -> None:
    """A board long along its y axis (OpenCV's 4 x 11 asymmetric circle grid), rolled by
    90 degrees, lies across a landscape image and spans more of its width than upright."""
    board = Board(board_type="acircles", cols=4, rows=11, square_length=0.03)
    cam = Camera.preset("webcam")
    spans = {}
    for roll in (0.0, 90.0):
        rng = np.random.default_rng(4)
        widths = []
        for rvec, tvec in random_poses(board, cam, 6, rng, partial_fraction=0.0,
                                       roll_centre_deg=roll):
            R = cv2.Rodrigues(rvec)[0]
            # the board's y axis in the image runs mostly along x once rolled
            y_axis = R[:, 1]
            assert (abs(y_axis[0]) > abs(y_axis[1])) == (roll == 90.0)
            px = project_points(cam, board.object_points(), rvec, tvec)
            widths.append(np.ptp(px[:, 0]) / cam.width)
        spans[roll] = float(np.median(widths))
    assert spans[90.0] > 1.2 * spans[0.0]
