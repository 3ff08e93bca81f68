"""A :class:`~artcal_ros.core.detect.detector.Detector`'s settings, one frozen dataclass."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from artcal_ros.core.errors import DetectionError

__all__ = ["DetectorConfig"]


@dataclass(frozen=True)
class DetectorConfig:
    """Tuning of :class:`Detector`; the defaults suit printed boards and ordinary cameras.

    Attributes:
        gamma: exponent from encoded grey to linear light (``(v / full_scale) ** gamma``):
            2.2 for sRGB-like 8-bit images, 1.0 for linear data; 0 (the default) estimates
            the tone curve from the edges (:mod:`.tone`), pooled over a Detector's frames.
        gamma_16bit: the same for 16-bit images (None: use ``gamma``).
        refine_edges: False keeps the quad finder's corners (for comparisons only).
        margin_px: edge profiles closer than this to a corner are skipped, pixels.
        curve_min_px: without a camera model, image sides at least this long are fitted
            as parabolas (lens distortion bends them), pixels.
        estimate_lens: without a camera model, estimate a division lens from those
            parabolas (plumb lines) and bend every side by it.
        max_bit_errors: most code cells (of bits^2) that may disagree with the id of a
            marker a neighbour supports.
        max_bit_errors_isolated: the same for a marker no neighbour vouches for; None
            rejects isolated markers.
        neighbour_tolerance: how far (marker sides) a neighbour may sit from where this
            marker's own homography puts it.
        min_side_px: quads with a shorter side are ignored, pixels.
        code_rows: code rows behind the border modelled by the edge fit (1 or 2).
        decode_rejected: decode the quads OpenCV could not read against the board's own
            patterns (recovers markers under blur and clipping).
        pool_lens: pool the lens estimate over a Detector's frames (one camera per
            detector; :meth:`Detector.reset_lens` forgets).
        adaptive_window_max: largest adaptive-threshold window of the quad finder, pixels.
        half_search_above_px: quads searched at half size first from this short side, px (0: off).
        edge_shift: remove each view's edge shift, measured from its markers' size against
            their pitch (:mod:`.edge_shift`); in a far over-exposed frame whose sides
            scatter, also move the corners toward the sides its neighbours place.
        censor_clipped: in an over-exposed frame whose ink is below 0.85 of saturation,
            fit the edges with the saturated pixels as censored data (docs/tone.md).
        grid_search: in an over-exposed frame, look for the markers the quad finder missed
            where the verified ones place them (:mod:`.grid_search`; marker grids only).
        stream: a Detector's frames are taken as consecutive frames of one stream: the
            markers the frames before verified are predicted, refined directly and the quad
            finder searches only the rest of the image (:mod:`.stream_predict`; a frame the
            prediction does not fit is searched whole). Off by default: it saves
            little while the edge fit dominates a frame (docs/history.md), and frames
            that do not follow each other (photos, the node's background views) would
            pay for a failed prediction.
    """

    gamma: float = 0.0
    gamma_16bit: float | None = None
    refine_edges: bool = True
    margin_px: float = 1.5
    curve_min_px: float = 20.0
    estimate_lens: bool = True
    code_rows: int = 1
    decode_rejected: bool = True
    pool_lens: bool = True
    max_bit_errors: int = 2
    max_bit_errors_isolated: int | None = 0
    neighbour_tolerance: float = 0.25
    min_side_px: float = 6.0
    adaptive_window_max: int = 33
    half_search_above_px: int = 1000
    edge_shift: bool = True
    censor_clipped: bool = True
    grid_search: bool = True
    stream: bool = False

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> DetectorConfig:
        """The configuration the parameters file asks for (``detector.gamma``)."""
        return cls(gamma=float(params.get("detector.gamma", 0.0)))

    def __post_init__(self) -> None:
        for name, g in (("gamma", self.gamma), ("gamma_16bit", self.gamma_16bit)):
            if g is not None and not (g >= 0 and np.isfinite(g)):
                raise DetectionError(f"DetectorConfig.{name}: {g} must be >= 0 (0: estimate "
                                     "from the images, 2.2 for sRGB-like images, 1.0 for "
                                     "linear data)")
        if self.adaptive_window_max < 3:
            raise DetectionError("DetectorConfig.adaptive_window_max must be >= 3")
