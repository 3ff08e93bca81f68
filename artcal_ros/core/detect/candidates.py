"""Candidate quads and ids: OpenCV's ArUco quad finder, and a second read of what it rejected.

OpenCV runs on the 8-bit, contrast-stretched image (both polarities when the
board has white-on-black markers). The quads it found but could not read are
decoded again against the board's own patterns, blur-aware
(:mod:`artcal_ros.core.detect.decode`); near misses are read once more on
quads refined from their edges. Only ids on the board survive, each once.

A large image may be searched at half resolution (a 2 x 2 mean of the 8-bit copy): the
quads found there are scaled back to full-resolution pixels and decoded and refined there.
Where the markers the half image finds have modules too small to threshold there, the
full-resolution search runs as well (markers of 1.25 px modules there are still read, on
their quads' full-resolution pixels, so a frame with none found is taken as empty). Mixed
boards and clipped frames are searched at full resolution only.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.decode import PatternTable, decode_quads
from artcal_ros.core.detect.edges import refine_quads, same_edges
from artcal_ros.core.detect.exposure import saturation_image
from artcal_ros.core.detect.sampling import border_is_dark
from artcal_ros.core.homography import shortest_sides

# a half-resolution search's markers need modules at least this wide there, pixels; below it
# the full-resolution search runs too
_HALF_MIN_MODULE_PX = 3.0


def half_image(gray8: np.ndarray) -> np.ndarray:
    """(H // 2, W // 2) mean of each 2 x 2 block of ``gray8`` (an odd last row or column
    dropped): half-image pixel (x, y) is centred on full-image (2x + 0.5, 2y + 0.5)."""
    h, w = gray8.shape[:2]
    even = gray8[: h - h % 2, : w - w % 2]
    return np.asarray(cv2.resize(even, (w // 2, h // 2), interpolation=cv2.INTER_AREA))


def _aruco_detector(board: Board, adaptive_window_max: int, window_step: int = 10
                    ) -> cv2.aruco.ArucoDetector:
    """OpenCV's marker detector for ``board``, as a quad finder (no corner refinement).

    Args:
        board: the calibration board (dictionary and polarity).
        adaptive_window_max: largest adaptive-threshold window, pixels (at least 3).
        window_step: step between the adaptive-threshold windows, pixels.
    """
    p = cv2.aruco.DetectorParameters()
    p.adaptiveThreshWinSizeStep = window_step
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE
    p.detectInvertedMarker = board.polarity != "black"
    p.minMarkerPerimeterRate = 0.01
    p.adaptiveThreshWinSizeMax = max(int(adaptive_window_max), 3)
    # markers whose border comes within a pixel or two of the image edge are still
    # whole; the edge fit ignores samples off the image
    p.minDistanceToBorder = 0
    return cv2.aruco.ArucoDetector(board.dictionary, p)


class CandidateFinder:
    """Finds the quads and ids of one board's markers in an image.

    Args:
        board: the calibration board.
        adaptive_window_max: largest adaptive-threshold window of the quad finder, pixels.
        decode_rejected: decode the quads OpenCV could not read against the board's
            own patterns (recovers markers under blur and clipping).
        min_side_px: quads with a shorter side are ignored, pixels.
        half_above_px: images whose short side is at least this are searched at half
            resolution first (0: never).
    """

    def __init__(self, board: Board, *, adaptive_window_max: int, decode_rejected: bool,
                 min_side_px: float, half_above_px: int = 0) -> None:
        self.board = board
        self.decode_rejected = decode_rejected
        self.min_side_px = min_side_px
        self.half_above_px = half_above_px
        self._aruco = _aruco_detector(board, adaptive_window_max)
        # the same windows in the half image's pixels (OpenCV makes each odd)
        self._aruco_half = _aruco_detector(board, max(adaptive_window_max // 2, 3), 5)
        # whether the last image was searched at full resolution
        self.full_searched = True
        self.patterns = PatternTable(board, any_polarity=board.polarity == "any")
        # the last image's quads that read almost as a marker (first pass only), for a
        # second read through the lens (:mod:`.rim`)
        self.near_misses: np.ndarray = np.zeros((0, 4, 2))
        self.clipped_patterns = PatternTable(board, any_polarity=board.polarity == "any",
                                              clipped=True)

    def find(self, gray8: np.ndarray, lin: np.ndarray, *, clipped: bool
             ) -> tuple[np.ndarray, np.ndarray]:
        """Quads (N, 4, 2) in board corner order and ids (N,) that belong to the board.

        Args:
            gray8: (H, W) uint8 image for the quad finder.
            lin: (H, W) float32 linear intensity of the same image.
            clipped: the frame is over-exposed (:func:`~.exposure.is_clipped`).
        """
        self.near_misses = np.zeros((0, 4, 2))
        self.full_searched = True
        # not for mixed boards, whose narrow quiet zones blur shut at half resolution, nor
        # for clipped frames, whose saturation mask loses the thin borders there
        if (0 < self.half_above_px <= min(gray8.shape[:2])
                and self.board.polarity in ("black", "white") and not clipped):
            quads, ids = self._search(half_image(gray8), lin, half=True)
            modules = shortest_sides(quads) / (2 * (self.board.bits + 2))
            self.full_searched = bool(len(ids) and np.median(modules) < _HALF_MIN_MODULE_PX)
            if self.full_searched:
                # the full image's quads first: small markers' half-image quads are coarse
                near = self.near_misses
                fq, fids = self._search(gray8, lin, half=False)
                new = ~np.isin(ids, fids)
                quads = np.concatenate([fq, quads[new]])
                ids = np.concatenate([fids, ids[new]])
                self.near_misses = np.concatenate([near, self.near_misses])
        else:
            quads, ids = self._search(gray8, lin, half=False)
        # an id seen twice is at least once wrong, and which one cannot be told here
        uniq, counts = np.unique(ids, return_counts=True)
        single = np.isin(ids, uniq[counts == 1])
        quads, ids = quads[single], ids[single]
        big = shortest_sides(quads) >= self.min_side_px
        return quads[big], ids[big]

    def _search(self, gray8: np.ndarray, lin: np.ndarray, *, half: bool
                ) -> tuple[np.ndarray, np.ndarray]:
        """Quads (N, 4, 2) in full-resolution pixels and ids (N,) found in ``gray8`` (the
        image, or its half-resolution copy), a clipped frame's saturation mask searched too;
        an id may repeat."""
        quads, ids = self._pass(gray8, lin, half=half)
        bright = saturation_image(gray8)
        if bright is not None:
            # only ids the first pass lacks: the same marker read twice would be dropped
            # as an id seen twice
            bq, bids = self._pass(bright, lin, self.clipped_patterns, half=half)
            new = ~np.isin(bids, ids)
            quads = np.concatenate([quads, bq[new]])
            ids = np.concatenate([ids, bids[new]])
        return quads, ids

    def _pass(self, gray8: np.ndarray, lin: np.ndarray, patterns: PatternTable | None = None,
              *, half: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """One pass of the quad finder: quads (N, 4, 2) and ids (N,) on the board (an id
        may repeat), OpenCV's reads first, then its rejected quads decoded here against
        ``patterns`` (default: the board's, unclipped). ``half``: ``gray8`` is the half
        image; the quads are returned in full-resolution pixels."""
        aruco = self._aruco_half if half else self._aruco
        corners, ids_cv, found = aruco.detectMarkers(gray8)
        rejected: Any = found
        if ids_cv is None or len(ids_cv) == 0:
            quads: np.ndarray = np.zeros((0, 4, 2))
            ids: np.ndarray = np.zeros(0, dtype=np.int64)
        else:
            quads = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
            ids = np.asarray(ids_cv, dtype=np.int64).reshape(-1)  # type: ignore[assignment]
        if half:
            quads = 2 * quads + 0.5
            if rejected is not None and len(rejected):
                rejected = 2 * np.asarray(rejected, dtype=np.float64) + 0.5
        on_board = (ids >= self.board.first_id) & (ids <= int(self.board.ids[-1]))
        quads, ids = quads[on_board], ids[on_board]
        if self.decode_rejected and rejected is not None and len(rejected):
            dq, dids = self._decode_rejected(lin, rejected, patterns or self.patterns)
            new = ~np.isin(dids, ids)
            quads = np.concatenate([quads, dq[new]])
            ids = np.concatenate([ids, dids[new]])
        return quads, ids

    def _decode_rejected(self, lin: np.ndarray, rejected: Any, patterns: PatternTable
                         ) -> tuple[np.ndarray, np.ndarray]:
        """Quads (D, 4, 2) in board corner order and ids (D,) read from OpenCV's rejected quads.

        Args:
            lin: (H, W) float32 linear intensity image.
            rejected: OpenCV's rejected candidates (a sequence of (1, 4, 2) arrays).
            patterns: what the quads are matched against.
        """
        found = np.asarray(rejected, dtype=np.float64).reshape(-1, 4, 2)
        rq = found[shortest_sides(found) >= self.min_side_px]
        dq, dids, taken, err = decode_quads(lin, rq, patterns)
        # near misses: re-read on quads refined from their edges (the quad finder's
        # corners misplace the code cells of small or blurred markers)
        near = (err > 2) & (err <= 10)
        near[taken] = False
        if patterns is self.patterns:
            self.near_misses = rq[near]
        if near.any():
            nq = rq[near]
            dark = border_is_dark(lin, nq, self.board.bits)
            fit = refine_quads(lin, nq, dark, self.board.bits, allow_curvature=False, passes=1)
            good = fit.ok & same_edges(fit.corners_px, nq)
            rq2, rids2, _, _ = decode_quads(lin, fit.corners_px[good], patterns,
                                            grow_px=0.0)
            dq = np.concatenate([dq, rq2])
            dids = np.concatenate([dids, rids2])
        return dq, dids
