"""A Detector fed consecutive frames: markers predicted from the frames before, refined
directly, against the renderer's truth and against the same frames detected without it."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, DetectorConfig
from artcal_ros.core.detect.frames import detect_frames
from artcal_ros.core.detections import Detections
from artcal_ros.synth import Camera, RenderedView, render_view
from artcal_ros.synth.backdrop import Backdrop
from artcal_ros.synth.poses import ease_between, random_poses

SMALL = Board(cols=6, rows=4)
CAM = Camera.preset("webcam")
STREAM = DetectorConfig(stream=True)  # consecutive frames: the markers predicted


def _pose(board: Board, x_m: float, y_m: float, z_m: float, roll_deg: float = 0.0,
          tilt_deg: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """A pose T_cam_board with the board's centre at (x, y, z) in the camera frame, turned
    ``roll_deg`` about the optical axis and tilted ``tilt_deg`` about its own x axis."""
    w, h = board.size_m
    R = (cv2.Rodrigues(np.array([0.0, 0.0, np.radians(roll_deg)]))[0]
         @ cv2.Rodrigues(np.array([np.radians(tilt_deg), 0.0, 0.0]))[0])
    t = np.array([x_m, y_m, z_m]) - R @ np.array([w / 2, h / 2, 0.0])
    return cv2.Rodrigues(R)[0].ravel(), t


def _wrong(dets: Detections, truths: list[RenderedView], tol_px: float = 1.0) -> int:
    """Markers not within ``tol_px`` of the truth of their id in any of ``truths`` (a view
    of each board in the frame; corner order included)."""
    wrong = 0
    for i, c in zip(dets.ids, dets.corners_px, strict=True):
        near = [np.abs(c - v.corners_px[np.flatnonzero(v.ids == i)[0]]).max()
                for v in truths if i in v.ids]
        wrong += not near or min(near) > tol_px
    return wrong


def _composite(left: RenderedView, right: RenderedView) -> np.ndarray:
    """The left half of one frame beside the right half of another."""
    out = left.image.copy()
    half = out.shape[1] // 2
    out[:, half:] = right.image[:, half:]
    return out


@pytest.fixture(scope="module")
def sweep() -> list[RenderedView]:
    """14 frames of a hand-held sweep (the full board, cluttered wall behind)."""
    board = Board()
    rng = np.random.default_rng(7)
    wall = Backdrop.random(board, np.random.default_rng([7, 2]))
    keys = random_poses(board, CAM, 3, rng)
    return [render_view(board, CAM, r, t, rng=rng, backdrop=wall)
            for r, t in ease_between(keys, 14, frames_per_key=12)]


def test_streamed_sweep_matches_cold_frame_by_frame(sweep: list[RenderedView]) -> None:
    board = Board()
    streamed, plain = Detector(board, STREAM), Detector(board)
    predicted, err_s, err_p, found_s, found_p = 0, [], [], 0, 0
    for view in sweep:
        s, p = streamed.detect(view.image), plain.detect(view.image)
        predicted += streamed.predicted
        assert _wrong(s, [view]) == 0
        found_s, found_p = found_s + len(s), found_p + len(p)
        common, i_s, i_p = np.intersect1d(s.ids, p.ids, return_indices=True)
        # the same edges fitted from another start: the same corners to a fraction of
        # their error
        assert np.abs(s.corners_px[i_s] - p.corners_px[i_p]).max() < 0.15
        truth = view.corners_px[np.searchsorted(view.ids, common)]
        err_s.append(s.corners_px[i_s] - truth)
        err_p.append(p.corners_px[i_p] - truth)
    assert predicted >= len(sweep) // 2, "the prediction held on too few frames"
    assert found_s >= 0.99 * found_p
    rms_s = np.sqrt(np.mean(np.concatenate(err_s) ** 2))
    rms_p = np.sqrt(np.mean(np.concatenate(err_p) ** 2))
    assert rms_s <= 1.05 * rms_p


def test_board_leaving_turning_and_returning_gives_no_wrong_id() -> None:
    rng = np.random.default_rng(3)
    poses = ([_pose(SMALL, x, 0.0, 1.0) for x in np.linspace(-0.05, 1.15, 9)]  # leaves
             + [_pose(SMALL, 0.0, 0.0, 1.0, roll) for roll in (0, 3, 6, 50, 95, 140, 185)])
    views = [render_view(SMALL, CAM, r, t, rng=rng) for r, t in poses]
    det = Detector(SMALL, STREAM)
    found = []
    for view in views:
        dets = det.detect(view.image)
        assert _wrong(dets, [view]) == 0
        found.append(len(dets))
    assert found[0] == SMALL.n_markers and found[8] == 0   # whole, then gone
    assert min(found[9:]) == SMALL.n_markers               # each turn found whole again


@pytest.mark.parametrize("other", [SMALL, Board(cols=6, rows=4, first_id=12)],
                         ids=["same board", "overlapping ids"])
def test_second_board_appearing_gives_no_wrong_id(other: Board) -> None:
    rng = np.random.default_rng(5)
    det = Detector(SMALL, STREAM)
    ours = [render_view(SMALL, CAM, *_pose(SMALL, -0.3 + 0.005 * k, 0.0, 1.2), rng=rng)
            for k in range(8)]
    theirs = render_view(other, CAM, *_pose(other, 0.27, 0.02, 1.2, 20.0), rng=rng)
    only_ours = SMALL.ids[~np.isin(SMALL.ids, other.ids)]
    for k, view in enumerate(ours):
        image = view.image if k < 3 else _composite(view, theirs)
        dets = det.detect(image)
        assert _wrong(dets, [view] + ([theirs] if k >= 3 else [])) == 0
        # (two copies of every id: none is kept, as a cold search keeps none)
        assert other is SMALL or k < 2 or k == 3 or det.predicted, k
        # the markers only our board has are still found beside the other board
        assert np.isin(only_ours, dets.ids).all()


def test_restore_starts_a_run_afresh() -> None:
    """A run restored from a snapshot detects its first frame as a cold search would: the
    results of detect_frames' runs do not depend on which detector ran before."""
    rng = np.random.default_rng(9)
    views = [render_view(SMALL, CAM, *_pose(SMALL, 0.01 * k, 0.0, 1.0), rng=rng)
             for k in range(3)]
    a, b = Detector(SMALL, STREAM), Detector(SMALL, STREAM)
    state = a.snapshot()
    for view in views:
        a.detect(view.image)
    a.restore(state)
    b.restore(state)
    da, db = a.detect(views[2].image), b.detect(views[2].image)
    assert not a.predicted and not b.predicted
    np.testing.assert_array_equal(da.ids, db.ids)
    np.testing.assert_array_equal(da.corners_px, db.corners_px)


def test_a_recordings_runs_give_the_same_results_on_any_number_of_workers(
        sweep: list[RenderedView]) -> None:
    """detect_frames on consecutive frames (the runs predict from their own frames only)."""
    frames = [(str(k), v.image) for k, v in enumerate(sweep[:11])]
    one, two = (list(detect_frames(frames, Detector(Board(), STREAM), workers=w, warmup=2,
                                   run=3))
                for w in (1, 2))
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(a.corners_px, b.corners_px)
