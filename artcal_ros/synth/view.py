"""Rendering one view of the board: the image and its exact truth."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ParameterError
from artcal_ros.synth.backdrop import Backdrop
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.photometry import (
    ENCODINGS,
    Photometry,
    blur,
    sense_and_encode,
    vignette,
)
from artcal_ros.synth.poses import marker_truth, point_truth
from artcal_ros.synth.render import board_coverage
from artcal_ros.synth.truth import FrameTruth, frame_record


@dataclass(frozen=True, kw_only=True)
class RenderedView(FrameTruth):
    """A rendered frame and its truth (fields of :class:`~artcal_ros.synth.truth.FrameTruth`;
    ``ids`` every marker of the board, visible or not).

    Attributes:
        image: (H, W) uint8 (mono8), (H, W) uint16 (mono16) or (H, W, 3) uint8 (bgr8/rgb8;
            BGR channel order in both cases, like ``images.image_to_numpy``).
        encoding: the image's encoding name.
    """

    image: np.ndarray
    encoding: str

    def true_detections(self, *, min_side_px: float = 0.0) -> Detections:
        """The markers (and points) inside the image as perfect :class:`Detections` (true
        points), optionally only markers whose image side is at least ``min_side_px``."""
        h, w = self.image.shape[:2]
        return self.perfect_detections((w, h), source="synth", min_side_px=min_side_px)

    def truth_record(self, *, file: str | None = None,
                     stamp_ns: int | None = None) -> dict[str, object]:
        """This frame's record for ``truth.json`` (see :mod:`artcal_ros.synth.truth`)."""
        return frame_record(rvec=self.rvec, tvec=self.tvec, ids=self.ids,
                            corners_px=self.corners_px, centers_px=self.centers_px,
                            inside=self.inside, side_px=self.side_px, file=file,
                            stamp_ns=stamp_ns, point_ids=self.point_ids,
                            points_px=self.points_px, points_inside=self.points_inside)


_LUMA = np.array([0.2126, 0.7152, 0.0722])   # linear RGB -> luminance


def render_linear(board: Board, cam: Camera, rvec: np.ndarray, tvec: np.ndarray, *,
                  photometry: Photometry | None = None, rng: np.random.Generator | None = None,
                  color: bool = False, backdrop: Backdrop | None = None) -> np.ndarray:
    """Linear radiance reaching the sensor, after optics, before exposure and noise.

    Args:
        board, cam: what is seen and by what.
        rvec, tvec: T_cam_board (Rodrigues vector; metres).
        photometry: light and optics (default :meth:`Photometry.clean`). With
            :meth:`Photometry.exact` the result is each pixel's white area fraction.
        rng: source of the random lighting direction, clutter and blur direction.
        color: return (H, W, 3) linear RGB instead of (H, W) luminance.
        backdrop: the cluttered wall behind the board (when ``photometry.clutter``); None
            makes a new random one. Pass the same one to every frame of a sequence so the
            background stays put as the camera moves.

    Returns:
        (H, W) or (H, W, 3) float64; 1.0 is full scale at exposure 1.
    """
    phot = photometry if photometry is not None else Photometry.clean()
    rng = rng if rng is not None else np.random.default_rng(0)
    cov = board_coverage(board, cam, rvec, tvec)
    # light falls off linearly across the board in a random direction
    w_m, h_m = board.size_m
    psi = rng.uniform(0, 2 * math.pi)
    half_diag = 0.5 * math.hypot(w_m, h_m)
    along = ((cov.bx - w_m / 2) * math.cos(psi) + (cov.by - h_m / 2) * math.sin(psi)) / half_diag
    light = phot.illumination * np.maximum(1.0 + phot.gradient * along, 0.0)
    board_rad = cov.alpha * light * (phot.ink + (phot.paper - phot.ink) * cov.white)
    if phot.clutter:
        wall = backdrop if backdrop is not None else Backdrop.random(board, rng)
        back = wall.render(cam, rvec, tvec)
    else:
        back = np.full((cam.height, cam.width, 3), 0.15, dtype=np.float32)
    tint = np.asarray(phot.tint, dtype=np.float64)
    if color:
        lin = (board_rad[..., None] + (1.0 - cov.alpha)[..., None] * (back * phot.background))
        lin *= tint
    else:
        back_luma = back @ (tint * _LUMA * phot.background).astype(np.float32)
        lin = board_rad * float(tint @ _LUMA) + (1.0 - cov.alpha) * back_luma
    lin = blur(lin, phot, rng)
    if phot.vignetting > 0:
        v = vignette(cam.size, phot.vignetting)
        lin = lin * (v[..., None] if color else v)
    return np.asarray(lin)


def render_view(board: Board, cam: Camera, rvec: np.ndarray, tvec: np.ndarray, *,
                photometry: Photometry | None = None, rng: np.random.Generator | None = None,
                encoding: str = "mono8", backdrop: Backdrop | None = None) -> RenderedView:
    """Render one frame (see :func:`render_linear`) and its truth.

    Args:
        photometry, rng, backdrop: as for :func:`render_linear`.
        encoding: ``mono8`` | ``mono16`` | ``bgr8`` | ``rgb8``.
    """
    if encoding not in ENCODINGS:
        raise ParameterError(f"unknown encoding {encoding!r}; use one of {', '.join(ENCODINGS)}")
    phot = photometry if photometry is not None else Photometry.clean()
    rng = rng if rng is not None else np.random.default_rng(0)
    rvec = np.asarray(rvec, dtype=np.float64).reshape(3)
    tvec = np.asarray(tvec, dtype=np.float64).reshape(3)
    color = encoding in ("bgr8", "rgb8")
    lin = render_linear(board, cam, rvec, tvec, photometry=phot, rng=rng, color=color,
                        backdrop=backdrop)
    image = sense_and_encode(lin, phot, rng, encoding)
    corners, centers, inside, side = marker_truth(board, cam, rvec, tvec)
    # an aprilgrid's points are its tag corners: their truth is the markers'
    point_ids, points, points_inside = np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0, bool)
    if board.has_points:
        point_ids = board.point_ids.copy()
        points, points_inside, _ = point_truth(board, cam, rvec, tvec)
    return RenderedView(image=image, encoding=encoding, rvec=rvec, tvec=tvec,
                        ids=board.ids.copy(), corners_px=corners, centers_px=centers,
                        inside=inside, side_px=side, point_ids=point_ids,
                        points_px=points, points_inside=points_inside)
