"""One rule for a frame's perfect detections, whether the truth comes from a render or from
its truth.json record: markers wholly inside the image, filtered by side only where the side
is known."""

from __future__ import annotations

import json

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
from artcal_ros.synth.truth import truth_frame


def _view_and_record() -> tuple[object, dict]:
    board = Board()
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(12)
    for rvec, tvec in random_poses(board, cam, 6, rng, partial_fraction=1.0):
        view = render_view(board, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
        if 0 < view.inside.sum() < len(view.ids):  # a partial view: some markers outside
            record = json.loads(json.dumps(view.truth_record(file="frame.png")))
            return view, record
    raise AssertionError("no partial view among the poses")


def test_render_and_its_record_give_the_same_perfect_detections() -> None:
    view, record = _view_and_record()
    frame = truth_frame(record)
    size = view.image.shape[1], view.image.shape[0]
    median_side = float(np.median(view.side_px[view.inside]))
    for min_side in (0.0, median_side):
        a = view.true_detections(min_side_px=min_side)
        b = frame.true_detections(size, min_side_px=min_side)
        assert np.array_equal(a.ids, b.ids) and len(a) > 0
        assert np.max(np.abs(a.corners_px - b.corners_px)) < 1e-6  # truth.json rounds to 1e-7
    kept = view.true_detections(min_side_px=median_side)
    side = dict(zip(view.ids.tolist(), view.side_px.tolist(), strict=True))
    inside_ids = set(view.ids[view.inside].tolist())
    assert all(side[i] >= median_side for i in kept.ids.tolist())
    assert all(side[i] < median_side for i in inside_ids - set(kept.ids.tolist()))
    assert len(view.true_detections()) == len(inside_ids) < len(view.ids)


def test_a_record_without_sides_keeps_its_inside_markers_under_any_size_filter() -> None:
    view, record = _view_and_record()
    for marker in record["markers"]:
        del marker["side_px"]
    frame = truth_frame(record)
    assert np.all(np.isnan(frame.side_px))
    size = view.image.shape[1], view.image.shape[0]
    expected = np.sort(view.ids[view.inside])
    for min_side in (0.0, 1e9):
        dets = frame.true_detections(size, min_side_px=min_side)
        assert np.array_equal(np.sort(dets.ids), expected)
