"""A marker grid near the rim of a fisheye image is still found (issue 24, Table 2).

Far out in an equidistant lens a marker's own homography no longer predicts where its
neighbours are, nor where its modules lie: verification reads such markers again through
the lens the edge fit estimated, and the quad finder's near misses are decoded through it.
"""

from __future__ import annotations

import numpy as np

from artcal_ros import Board, detect
from artcal_ros.synth import Camera, Photometry, render_view
from artcal_ros.synth.poses import marker_truth

# the Table-2 marker grid, light and a pose of bench.paper_table2 (fisheye, corner pose)
BOARD = Board(cols=10, rows=8, marker_length=0.0225, marker_separation=0.0075)
LIGHT = Photometry(gradient=0.3, vignetting=0.3, defocus_px=1.0, full_well=4000.0,
                   read_noise=6.0)


def _found(rvec: list[float], tvec: list[float], seed: int, least: int) -> None:
    """The markers detected in the render are the board's, in view, where the truth puts
    them; at least ``least`` of them."""
    cam = Camera.preset("fisheye")
    r, t = np.array(rvec), np.array(tvec)
    view = render_view(BOARD, cam, r, t, photometry=LIGHT, rng=np.random.default_rng(seed))
    corners, centers, inside, _ = marker_truth(BOARD, cam, r, t)
    det = detect(view.image, BOARD)
    assert len(det.ids) >= least
    rows = det.ids - BOARD.first_id
    assert inside[rows].all()
    err = np.linalg.norm(det.corners_px - corners[rows], axis=2)
    # markers 13-55 px at the rim of the lens: their edges are fitted with the frame's own
    # lens estimate, a few tenths of a pixel off, never a misplaced corner (one module is
    # 4-7 px here)
    assert np.sqrt(np.mean(err ** 2)) < 0.4
    assert err.max() < 1.5
    assert np.linalg.norm(det.centers_px - centers[rows], axis=1).max() < 0.6


def test_markers_at_the_fisheye_rim_pass_verification() -> None:
    # in the image the markers' homographies contradict their neighbours: none was kept
    _found([-0.05998, -0.412476, -0.163744], [0.022621, -0.223411, 0.067921], 2413017, 8)


def test_near_misses_at_the_fisheye_rim_are_read_through_the_lens() -> None:
    # OpenCV reads none of these markers and a homography decodes 2 of them
    _found([-0.511332, 0.163429, 0.194428], [-0.291797, -0.250072, 0.206297], 2413016, 5)
