"""Candidate quads and ids: OpenCV's ArUco quad finder, and a second read of what it rejected.

OpenCV runs on the 8-bit, contrast-stretched image (both polarities when the
board has white-on-black markers). The quads it found but could not read are
decoded again against the board's own patterns, blur-aware
(:mod:`artcal_ros.core.detect.decode`); near misses are read once more on
quads refined from their edges. Only ids on the board survive, each once.
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


def _aruco_detector(board: Board, adaptive_window_max: int) -> cv2.aruco.ArucoDetector:
    """OpenCV's marker detector for ``board``, as a quad finder (no corner refinement).

    Args:
        board: the calibration board (dictionary and polarity).
        adaptive_window_max: largest adaptive-threshold window, pixels (at least 3).
    """
    p = cv2.aruco.DetectorParameters()
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
    """

    def __init__(self, board: Board, *, adaptive_window_max: int, decode_rejected: bool,
                 min_side_px: float) -> None:
        self.board = board
        self.decode_rejected = decode_rejected
        self.min_side_px = min_side_px
        self._aruco = _aruco_detector(board, adaptive_window_max)
        self.patterns = PatternTable(board, any_polarity=board.polarity == "any")
        # the last image's quads that read almost as a marker (first pass only), for a
        # second read through the lens (:mod:`.rim`)
        self.near_misses: np.ndarray = np.zeros((0, 4, 2))
        self.clipped_patterns = PatternTable(board, any_polarity=board.polarity == "any",
                                              clipped=True)

    def find(self, gray8: np.ndarray, lin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Quads (N, 4, 2) in board corner order and ids (N,) that belong to the board.

        Args:
            gray8: (H, W) uint8 image for the quad finder.
            lin: (H, W) float32 linear intensity of the same image.
        """
        self.near_misses = np.zeros((0, 4, 2))
        quads, ids = self._pass(gray8, lin)
        bright = saturation_image(gray8)
        if bright is not None:
            # only ids the first pass lacks: the same marker read twice would be dropped
            # below as an id seen twice
            bq, bids = self._pass(bright, lin, self.clipped_patterns)
            new = ~np.isin(bids, ids)
            quads = np.concatenate([quads, bq[new]])
            ids = np.concatenate([ids, bids[new]])
        # an id seen twice is at least once wrong, and which one cannot be told here
        uniq, counts = np.unique(ids, return_counts=True)
        single = np.isin(ids, uniq[counts == 1])
        quads, ids = quads[single], ids[single]
        big = shortest_sides(quads) >= self.min_side_px
        return quads[big], ids[big]

    def _pass(self, gray8: np.ndarray, lin: np.ndarray, patterns: PatternTable | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
        """One pass of the quad finder: quads (N, 4, 2) and ids (N,) on the board (an id
        may repeat), OpenCV's reads first, then its rejected quads decoded here against
        ``patterns`` (default: the board's, unclipped)."""
        corners, ids_cv, rejected = self._aruco.detectMarkers(gray8)
        if ids_cv is None or len(ids_cv) == 0:
            quads: np.ndarray = np.zeros((0, 4, 2))
            ids: np.ndarray = np.zeros(0, dtype=np.int64)
        else:
            quads = np.asarray(corners, dtype=np.float64).reshape(-1, 4, 2)
            ids = np.asarray(ids_cv, dtype=np.int64).reshape(-1)  # type: ignore[assignment]
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
