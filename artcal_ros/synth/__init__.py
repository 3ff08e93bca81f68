"""Physically plausible rendering of the calibration board with exact ground truth.

Used by the tests, the demo and the benchmarks::

    from artcal_ros.synth import Camera, Photometry, random_poses, render_view
    cam = Camera.preset("webcam")             # webcam | hd | wide | lowcost | fisheye
    rng = np.random.default_rng(1)
    for rvec, tvec in random_poses(board, cam, 20, rng, partial_fraction=0.3):
        view = render_view(board, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng)
        view.image, view.ids, view.corners_px, view.centers_px, view.inside

How it works (why the truth is exact): every pixel is rendered by inverse
mapping (pixel -> the lens model's exact inverse -> viewing ray -> board plane
-> the board's analytic print), and the print's area coverage of each pixel is
computed in closed form (see :mod:`artcal_ros.synth.render`), so edges
sit where the forward model -- the one the truth points come from, identical to
``cv2.projectPoints`` / ``cv2.fisheye.projectPoints`` -- puts them, to well
under 0.01 px. Light, optics and sensor follow in linear light
(:mod:`artcal_ros.synth.photometry`).

Pose convention: T_cam_board (rvec Rodrigues, tvec metres), ``p_cam = R p_board + t``.

Measuring edges against the truth: use :meth:`Photometry.exact` (or
:func:`render_linear`): linear light, no noise, unit contrast. In gamma-encoded
output the grey midpoint of a blurred edge is *not* the edge.
"""

from artcal_ros.synth.backdrop import Backdrop
from artcal_ros.synth.camera import PRESETS, Camera, project_points, rays_from_pixels
from artcal_ros.synth.photometry import ENCODINGS, Photometry
from artcal_ros.synth.poses import marker_truth, random_poses, smooth_poses
from artcal_ros.synth.truth import (
    Truth,
    TruthFrame,
    board_params,
    frame_record,
    load_truth,
    write_truth,
)
from artcal_ros.synth.view import RenderedView, render_linear, render_view

__all__ = [
    "ENCODINGS", "PRESETS", "Backdrop", "Camera", "Photometry", "RenderedView", "Truth",
    "TruthFrame",
    "board_params", "frame_record", "load_truth", "marker_truth", "project_points",
    "random_poses", "rays_from_pixels", "render_linear", "render_view", "smooth_poses",
    "write_truth",
]
