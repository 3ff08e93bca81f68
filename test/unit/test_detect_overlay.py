"""``artcal detect --overlay`` pictures: on a ChArUco board no id label covers another kind's,
and a legend names the colours."""

from __future__ import annotations

import numpy as np

from artcal_ros import Board
from artcal_ros.cli.detect_overlay import LEGEND, draw_detections, labels
from artcal_ros.core.detect import detect
from artcal_ros.core.detections import Detections
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.photometry import Photometry
from artcal_ros.synth.poses import random_poses
from artcal_ros.synth.view import render_view

CHARUCO = Board(board_type="charuco", cols=7, rows=5, square_length=0.05, marker_length=0.037)


def _charuco_view() -> tuple[np.ndarray, Detections]:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(3)
    rvec, tvec = random_poses(CHARUCO, cam, 1, rng)[0]
    view = render_view(CHARUCO, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
    return view.image, detect(view.image, CHARUCO)


def test_marker_and_point_ids_do_not_cover_each_other_on_charuco() -> None:
    _image, dets = _charuco_view()
    assert len(dets) >= 10 and len(dets.point_ids) >= 15
    placed = labels(dets, thick=1)
    markers = [lb for lb in placed if lb.kind == "marker"]
    points = [lb for lb in placed if lb.kind == "point"]
    crossed = [(m.text, p.text) for m in markers for p in points if m.overlaps(p)]
    assert crossed == [], f"marker ids over point ids: {crossed}"
    # every marker id sits inside its own marker's outline
    for lb, quad in zip(markers, dets.corners_px, strict=True):
        x0, y0 = quad.min(axis=0)
        x1, y1 = quad.max(axis=0)
        assert x0 <= lb.x0 and lb.x1 <= x1 and y0 <= lb.y0 and lb.y1 <= y1, lb


def test_the_picture_carries_a_legend_of_its_colours() -> None:
    image, dets = _charuco_view()
    picture = draw_detections(image, dets)
    assert picture.shape == (*image.shape[:2], 3)
    names = [name for name, _ in LEGEND]
    assert "marker id" in names and "board point, id" in names
    # the legend's text, in each of its colours, is in the top-left corner
    corner = picture[:16 * len(LEGEND) + 6, :160].astype(int)
    for name, colour in LEGEND:
        assert (np.abs(corner - colour).sum(axis=2) < 60).any(), f"no {name} colour in the legend"
