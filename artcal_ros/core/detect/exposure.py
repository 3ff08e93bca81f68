"""Exposure checks of a frame: clipped, partly saturated, compressed saturation, and the
levels the edge fit censors at and the ink reads at in a saturated frame.

See docs/tone.md (clipped frames) for what the detector does with each.
"""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.detect.sampling import ring_median, ring_points
from artcal_ros.core.detect.tone import ToneCurve
from artcal_ros.core.homography import module_homographies

# share of pixels at the frame's maximum from which it counts as clipped (an ordinary
# frame has a few specular or white-wall pixels there, not a sixth of the picture)
CLIPPED_SHARE = 0.15
# a frame with this share of pixels at a maximum of at least this level has saturated
# patches (a brighter part of the light on the paper) whose edges need censored fits
SATURATED_SHARE = 0.005
SATURATED_LEVEL = 250
# see compressed_plateau
PLATEAU_SPREAD = 0.3
_PLATEAU_LEVELS = 6


def _at_top(gray8: np.ndarray) -> tuple[int, np.ndarray, int]:
    """The frame's top level, every other pixel of every other row (its sample of the
    frame) and how many of that sample are at the top."""
    top = int(gray8.max())
    sub = gray8[::2, ::2]
    return top, sub, int(np.count_nonzero(sub >= top))


def is_clipped(gray8: np.ndarray) -> bool:
    """At least :data:`CLIPPED_SHARE` of the frame at its (bright) maximum: over-exposed.

    Args:
        gray8: (H, W) uint8 image for the quad finder.
    """
    top, sub, at = _at_top(gray8)
    # (a dark frame's maximum is not saturation, however many pixels share it)
    return top >= 200 and at >= CLIPPED_SHARE * sub.size


def saturates(gray8: np.ndarray) -> bool:
    """Part of the frame is saturated: at least :data:`SATURATED_SHARE` of it at a maximum
    of :data:`SATURATED_LEVEL` or more (a clipped patch of paper, not a specular glint).

    Args:
        gray8: (H, W) uint8 image for the quad finder.
    """
    top, sub, at = _at_top(gray8)
    return top >= SATURATED_LEVEL and at >= SATURATED_SHARE * sub.size


def compressed_plateau(gray8: np.ndarray) -> bool:
    """The frame's saturated patches look compressed: the few levels below the top hold at
    least :data:`PLATEAU_SPREAD` times as many pixels as the top itself.

    A sensor clips to one level; JPEG spreads a clipped patch over the levels just below it
    (ringing at its edges, rounded block means): measured 0.36 - 0.87 at quality 70 - 95
    and exposures up to 5 times over, 0.01 - 0.26 without it (the most where much paper is
    just below saturation).

    Args:
        gray8: (H, W) uint8 image for the quad finder.
    """
    top, sub, at = _at_top(gray8)
    below = np.count_nonzero(sub >= top - _PLATEAU_LEVELS) - at
    return below >= PLATEAU_SPREAD * at


# samples within this share of full scale (encoded) of the frame's top level count as
# saturated: JPEG spreads a clipped patch's edge over the levels below its top
CENSOR_MARGIN = 0.06


def censor_level(curve: ToneCurve, gray: np.ndarray, gray8: np.ndarray) -> float:
    """The linear level from which a frame's samples count as saturated in the edge fit:
    its top level, or :data:`CENSOR_MARGIN` below it in a compressed frame
    (:func:`compressed_plateau`).

    Args:
        curve: the frame's tone curve.
        gray: (H, W) uint8 or uint16 grey image.
        gray8: the same as uint8, for the quad finder.
    """
    full = 255.0 if gray.dtype == np.uint8 else 65535.0
    top = float(gray.max()) / full
    if compressed_plateau(gray8):
        return float(curve.to_linear(np.array([max(top - CENSOR_MARGIN, 0.0)]))[0])
    return float(curve.to_linear(np.array([top]))[0]) * 0.999


def dark_level(lin: np.ndarray, quads: np.ndarray, bits: int) -> float:
    """Median over the quads of the darker of their border and the ring just outside it.

    In a clipped frame that is the ink's level against saturation (1.0): how far over
    the paper is exposed, for a print of ordinary contrast.

    Args:
        lin: (H, W) linear intensity image (saturation at 1).
        quads: (M, 4, 2) marker corners, pixels.
        bits: code cells per marker side.

    Returns:
        the level (linear), NaN without quads.
    """
    if len(quads) == 0:
        return float("nan")
    n = bits + 2.0
    H = module_homographies(quads, bits)
    s = np.linspace(1.0, n - 1.0, 2 * (bits + 2))
    inside = ring_median(lin, H, ring_points(s, 0.5, n - 0.5))
    outside = ring_median(lin, H, ring_points(s, -0.5, n + 0.5))
    return float(np.median(np.minimum(inside, outside)))


def saturation_image(gray8: np.ndarray) -> np.ndarray | None:
    """A clipped frame as the quad finder should see it (None: the frame is not clipped).

    Once the paper clips, the ink is only a few grey levels below full scale (less than
    the finder's adaptive-threshold margin) and the white eats into every black module
    from both sides, breaking thin borders. What is left of the print is exactly what is
    not saturated: the image is that mask (255 saturated, 0 not), with the dark grown by
    a pixel (a 3 x 3 erosion) to close the gaps blooming leaves in a border. The quad
    then runs about a pixel outside the eaten border, near the printed one; the edge fit
    places the sides on the image itself.

    Args:
        gray8: (H, W) uint8 image for the quad finder.

    Returns:
        (H, W) uint8, or None when the frame is not clipped (:func:`is_clipped`).
    """
    if not is_clipped(gray8):
        return None
    top = int(gray8.max())
    mask = np.where(gray8 >= top, np.uint8(255), np.uint8(0))
    return np.asarray(cv2.erode(mask, np.ones((3, 3), np.uint8)))
