"""Coverage, view novelty, tilt and readiness (core.coverage), and the overlay pictures,
on exact projections of a known board through a known pinhole camera."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.coverage import CoverageConfig, ViewCollector, empty_regions, view_geometry
from artcal_ros.core.detections import Detections
from artcal_ros.core.overlay import render_heat_map, render_overlay
from artcal_ros.synth import Camera, project_points

BOARD = Board(cols=8, rows=5)  # 0.62 x 0.38 m
SIZE = (640, 480)
PINHOLE = Camera("plumb_bob", np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]]),
                 np.zeros(5), SIZE)


def view(yaw_deg: float = 0.0, pitch_deg: float = 0.0, distance: float = 1.0,
         shift: tuple[float, float] = (0.0, 0.0)) -> Detections:
    """Exact detections of the board's markers wholly inside the image: the board centre
    ``distance`` m ahead (moved by ``shift`` m), turned by ``yaw`` about the camera's y axis
    and ``pitch`` about its x axis."""
    R_yaw, _ = cv2.Rodrigues(np.array([0.0, math.radians(yaw_deg), 0.0]))
    R_pitch, _ = cv2.Rodrigues(np.array([math.radians(pitch_deg), 0.0, 0.0]))
    R = R_pitch @ R_yaw
    w, h = BOARD.size_m
    centre = np.array([w / 2, h / 2, 0.0])
    tvec = -R @ centre + np.array([shift[0], shift[1], distance])
    rvec = cv2.Rodrigues(R)[0].ravel()
    corners = project_points(PINHOLE, BOARD.object_corners().reshape(-1, 3), rvec, tvec)
    corners = corners.reshape(-1, 4, 2)
    inside = np.all((corners >= 0) & (corners <= np.array(SIZE) - 1), axis=(1, 2))
    centres = project_points(PINHOLE, BOARD.object_centers(), rvec, tvec)
    return Detections(BOARD.ids[inside], corners[inside], centres[inside], SIZE)


@pytest.mark.parametrize(("yaw", "pitch"), [(0, 0), (30, 0), (-30, 0), (0, 25), (20, -20)])
def test_tilt_estimate_follows_the_pose(yaw: float, pitch: float) -> None:
    g = view(yaw, pitch)
    # The estimate assumes f = image width (640) where the truth is 600: a few degrees off
    # at most, far inside the 15 degree "tilted" threshold it serves.
    assert abs(abs(g_x := view_geometry(g, BOARD).tilt_x_deg) - abs(yaw)) < 5, g_x
    assert abs(abs(view_geometry(g, BOARD).tilt_y_deg) - abs(pitch)) < 5
    assert 0.0 < view_geometry(g, BOARD).area_fraction < 1.0


def test_a_view_is_kept_once_and_only_with_enough_markers() -> None:
    collector = ViewCollector(BOARD, CoverageConfig(min_markers=6))
    frontal = view()
    assert collector.add(frontal)
    assert not collector.add(frontal), "the same view twice"
    # Moved by 5 mm at 1 m: ~3 px, below the 3% of the diagonal (24 px) that makes it new.
    assert not collector.add(view(shift=(0.005, 0.0)))
    assert collector.add(view(shift=(0.08, 0.0)))
    assert collector.add(view(yaw_deg=30))
    assert not collector.add(frontal.subset(np.arange(5))), "5 markers < min_markers"
    assert len(collector.views) == 3


def test_readiness_says_what_is_missing_until_it_is_ready() -> None:
    collector = ViewCollector(BOARD, CoverageConfig(min_views=4, min_coverage=0.5))
    collector.add(view(distance=2.5))  # small, frontal, in the middle
    r = collector.readiness()
    assert not r.ready and not r.enough_views
    assert r.missing[0] == "3 more views"
    assert any("top-left" in m and "bottom-right" in m for m in r.missing)
    assert "centre" not in empty_regions(collector.counts())
    assert any("left or right" in m for m in r.missing)
    assert any("up or down" in m for m in r.missing)
    for yaw, pitch, shift in [(30, 0, (-0.25, -0.1)), (-30, 0, (0.25, 0.1)),
                              (0, 30, (0.25, -0.15)), (0, -30, (-0.25, 0.15)),
                              (20, 20, (0.0, 0.0))]:
        collector.add(view(yaw, pitch, distance=1.1, shift=shift))
    r = collector.readiness()
    assert r.enough_views and r.ready, r.summary()
    assert r.coverage >= 0.5 and r.tilted_lr >= 2 and r.tilted_ud >= 2
    collector.reset()
    assert collector.readiness().views == 0 and collector.coverage() == 0.0


def test_a_new_image_size_starts_a_fresh_collection() -> None:
    collector = ViewCollector(BOARD)
    collector.add(view())
    other = view(yaw_deg=30)
    resized = Detections(other.ids, other.corners_px, other.centers_px, (800, 600))
    assert collector.add(resized)
    assert len(collector.views) == 1 and collector.image_size == (800, 600)


def test_pictures() -> None:
    collector = ViewCollector(BOARD)
    d = view()
    collector.add(d)
    image = np.full((SIZE[1], SIZE[0]), 128, np.uint8)
    picture = render_overlay(image, d, collector.counts(), collector.readiness(), kept=True)
    assert picture.shape == (480, 640, 3) and picture.dtype == np.uint8
    x, y = np.round(d.corners_px[0, 1]).astype(int)  # a quad's corner is drawn green
    assert picture[y, x, 1] > 150 and picture[y, x, 2] < 150
    heat = render_heat_map(collector.counts(), SIZE)
    assert heat.shape == (240, 320, 3)
    assert not heat[:5, :5].any(), "uncovered corner cells are black"
    assert heat[120, 160].any(), "the covered centre is coloured"
    assert not render_heat_map(np.zeros((9, 12), np.int64), SIZE).any()
