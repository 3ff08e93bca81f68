"""The detection pipeline: candidate quads, board-aware decoding, sub-pixel corners and centers.

The stages of one image, in :meth:`Detector.detect`'s order:

1. candidates: quads and ids from OpenCV's ArUco detector on an 8-bit copy, the quads it
   could not read decoded again against the board's own patterns (:mod:`.candidates`);
   only the board's ids, of the board's polarity. With ``DetectorConfig(stream=True)``,
   for consecutive frames, the markers the frames before verified are predicted first and
   the quad finder searches only the rest of the image (:mod:`.stream_predict`);
2. exposure: whether the frame is clipped or partly saturated (:mod:`.exposure`);
3. edges: every side fitted with a blurred-step model in linear light, bent by the lens
   (given, or estimated and pooled over frames), intersected into corners (:mod:`.edges`);
   the tone curve is probed on the same fits (:mod:`.tone`);
4. verification: code, neighbours and sides re-read on the refined quad, so a wrong id
   cannot reach the solver (:mod:`.verify`; through the lens when the image fails); the
   quad finder's near misses a strong lens distorts read again through it (:mod:`.rim`); a
   clipped frame's missing markers looked for where the verified ones place them
   (:mod:`.grid_search`);
5. centres, the diagonals' crossing through the lens (:mod:`.centers`), and the view's edge
   shift removed from the corners (:mod:`.edge_shift`).

A chessboard or circle grid goes to :mod:`.chessboard` or :mod:`.circles` instead; a ChArUco
board runs the marker stages, then :mod:`.charuco` places its corners from the markers.

Pixel convention: OpenCV's, the center of the top-left pixel is (0, 0).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.camera import CameraModel, HasCamera
from artcal_ros.core.detect.candidates import CandidateFinder
from artcal_ros.core.detect.centers import diagonal_centers
from artcal_ros.core.detect.charuco import charuco_corners
from artcal_ros.core.detect.chessboard import detect_chessboard
from artcal_ros.core.detect.circles import detect_circles
from artcal_ros.core.detect.config import DetectorConfig
from artcal_ros.core.detect.edge_shift import remove_view_shift
from artcal_ros.core.detect.edges import EdgeFit, refine_quads, same_edges
from artcal_ros.core.detect.exposure import censor_level, dark_level, is_clipped, saturates
from artcal_ros.core.detect.grid_search import grow
from artcal_ros.core.detect.image import sharpness, to_gray, to_gray8
from artcal_ros.core.detect.lens import DivisionLens, Lens, LensPool, LensPoolState, known_lens
from artcal_ros.core.detect.patterns import inner_border_cells, outer_neighbours
from artcal_ros.core.detect.rim import read_through_lens
from artcal_ros.core.detect.sampling import border_is_dark
from artcal_ros.core.detect.stream_predict import StreamPredictor
from artcal_ros.core.detect.tone import (
    ToneCurve,
    ToneEstimate,
    TonePool,
    ToneProbe,
    ToneState,
    differs,
)
from artcal_ros.core.detect.verify import checks_pass
from artcal_ros.core.detections import Detections

__all__ = ["Detector", "DetectorConfig", "detect"]


# a clipped frame's saturated samples are censored in the edge fit while its ink is darker
# than this share of saturation; beyond it too little of each edge's transition is left
# unclipped for censoring to help (bench.exposure)
_CENSOR_BELOW = 0.85
# a clipped frame's corners are moved toward the sides its neighbours place once its ink
# reads above this share of saturation, where blooming eats into the edges; below it the
# censored fit holds the edges and the sides' scatter is the frame's noise
_PLACE_ABOVE = 0.35

def _clear_of_edge(corners: np.ndarray, w: int, h: int, clear: float) -> np.ndarray:
    """(M,) bool: all four corners at least ``clear`` pixels inside the image."""
    x, y = corners[..., 0], corners[..., 1]
    inside = (x >= clear) & (x <= w - 1 - clear) & (y >= clear) & (y <= h - 1 - clear)
    return np.asarray(inside.all(axis=1) & np.isfinite(corners).all(axis=(1, 2)))


@dataclass(frozen=True)
class _Frame:
    """One image as the stages read it: grey as given (H, W), its 8-bit copy for the quad
    finder, linear light through ``curve``; ``probing``: the frame's edges probe the tone
    curve."""

    gray: np.ndarray
    gray8: np.ndarray
    lin: np.ndarray
    curve: ToneCurve
    probing: bool
    sharpness: float

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), pixels."""
        return self.gray.shape[1], self.gray.shape[0]


@dataclass(frozen=True)
class _Exposure:
    """A frame's exposure: clipped, its ink's level (share of saturation; 0 unless something
    saturates), whether the edge fit censors saturated samples, and whether it may refit
    sides in the frame's light field (not where anything saturates: :mod:`.light`)."""

    clipped: bool
    ink: float
    censor: bool
    light: bool


class _Markers(NamedTuple):
    """Markers between stages: ids (N,), corners (N, 4, 2) and their sigmas (N, 4), pixels."""

    ids: np.ndarray
    corners_px: np.ndarray
    sigma_px: np.ndarray


@dataclass(frozen=True)
class _Edges:
    """The edge stage's outcome: the frame (read through the tone curve the fit settled on),
    the markers whose edges fit and their borders' darkness (N,), the lens the centres are
    taken through, the one the sides were bent by, the fit's saturation level and light."""

    frame: _Frame
    markers: _Markers
    dark: np.ndarray
    lens: Lens | None
    fit_lens: Lens | None = None
    censor_at: float | None = None
    light: bool = True


class Detector:
    """A reusable detector for one board (markers, and points where the board has them).

    Args:
        board: the calibration board (its dictionary, ids and polarity).
        config: tuning, see :class:`DetectorConfig`.
    """

    def __init__(self, board: Board, config: DetectorConfig | None = None) -> None:
        self.board = board
        self.config = config or DetectorConfig()
        self._candidates: CandidateFinder | None = None
        if board.n_markers:
            self._candidates = CandidateFinder(
                board, adaptive_window_max=self.config.adaptive_window_max,
                decode_rejected=self.config.decode_rejected, min_side_px=self.config.min_side_px,
                half_above_px=self.config.half_search_above_px)
        self._lens_pool = LensPool()
        self._tone_pool = TonePool()
        # quiet zone around a marker's border, in modules (mixed boards: half the gap)
        self._quiet_modules = board.quiet_zone_m / board.module_length if board.bits else 0.0
        self._stream: StreamPredictor | None = None
        if self._candidates is not None and self.config.stream and self.config.refine_edges:
            self._stream = StreamPredictor(board, self._candidates,
                                           min_side_px=self.config.min_side_px,
                                           quiet_modules=self._quiet_modules)
        # ChArUco markers sit sqrt(2) squares apart at the closest (see neighbour_support)
        self._grow_to: float | None = None
        if board.board_type == "charuco":
            self._grow_to = 0.45 * np.sqrt(2.0) * board.square_length / board.marker_length

    def _outer_edges(self, ids: np.ndarray) -> np.ndarray | None:
        """Sides whose narrow quiet zone ends at a known edge: the next tile of a mixed board,
        the black square next to a ChArUco marker's white square.

        (On single-polarity marker grids the quiet zone is a whole gap wide and the
        edge window stops before it ends.)
        """
        if not self.board.tiles_touch:
            return None
        return outer_neighbours(self.board, ids)

    def reset_lens(self) -> None:
        """Forget the lens distortion learnt from earlier frames (a different camera)."""
        self._lens_pool.reset()

    def reset_tone(self) -> None:
        """Forget the tone curve learnt from earlier frames (a different camera)."""
        self._tone_pool.reset()

    def snapshot(self) -> tuple[LensPoolState, ToneState]:
        """What earlier frames taught this detector (lens, tone curve), for :meth:`restore`."""
        return self._lens_pool.snapshot(), self._tone_pool.snapshot()

    def restore(self, state: tuple[LensPoolState, ToneState]) -> None:
        """Go back to a :meth:`snapshot` (this detector's or another's of the same board);
        the next frame is not taken as following the last one (:meth:`reset_stream`)."""
        self._lens_pool.restore(state[0])
        self._tone_pool.restore(state[1])
        self.reset_stream()

    @property
    def predicted(self) -> bool:
        """Whether the last frame's markers came from the frames before (predicted and
        refined directly, the quad finder run only on the rest of the image)."""
        return self._stream is not None and self._stream.predicted

    def reset_stream(self) -> None:
        """The next frame does not follow the last one: search it whole, predict nothing."""
        if self._stream is not None:
            self._stream.reset()

    def _fixed_gamma(self, dtype: np.dtype) -> float:
        """The configured gamma for images of ``dtype`` (0: estimate)."""
        if dtype == np.uint16 and self.config.gamma_16bit is not None:
            return self.config.gamma_16bit
        return self.config.gamma

    @property
    def tone(self) -> ToneEstimate:
        """The tone curve of the last frames: estimated (pooled so far) or the configured one."""
        if self.config.gamma > 0:
            return ToneEstimate(ToneCurve("power", self.config.gamma), 0.0, False)
        return self._tone_pool.estimate()

    def _probe(self, curve: ToneCurve) -> ToneProbe:
        """A ``tone_probe`` for :func:`refine_quads` that adds a frame to the pool."""
        return ToneProbe(self._tone_pool, curve)

    def _refine(self, lin: np.ndarray, quads: np.ndarray, dark: np.ndarray, ids: np.ndarray,
                lens: Lens | None, probe: ToneProbe | None, censor_at: float | None = None,
                light: bool = True, pool: bool = True) -> EdgeFit:
        """The edge fit of every quad (:func:`refine_quads` with this detector's settings;
        ``censor_at``: samples at or above this linear level are censored; ``light``: sides
        refitted in the light field; ``pool``: the frame's lens evidence joins the pool)."""
        return refine_quads(lin, quads, dark, self.board.bits, margin_px=self.config.margin_px,
                            curve_min_px=self.config.curve_min_px, passes=1,
                            allow_curvature=lens is None and self.config.estimate_lens, lens=lens,
                            inner_same=inner_border_cells(self.board, ids,
                                                          rows=self.config.code_rows),
                            quiet_modules=self._quiet_modules,
                            outer_same=self._outer_edges(ids),
                            beyond_modules=self._quiet_modules,
                            lens_pool=self._lens_pool if self.config.pool_lens and pool
                            else None,
                            tone_probe=probe, censor_at=censor_at, light_field=light)

    def _dark(self, ids: np.ndarray) -> np.ndarray:
        """(N,) bool: the board prints these markers with a dark border."""
        return np.array([not self.board.is_inverted(int(i)) for i in ids], bool)

    def detect(self, image: np.ndarray, camera: CameraModel | HasCamera | None = None, *,
               source: str = "") -> Detections:
        """Detect the board's markers in one image.

        Args:
            image: (H, W) uint8/uint16 grey or (H, W, 3) uint8 BGR.
            camera: optional known camera: a :class:`~artcal_ros.core.camera.CameraModel`
                or a calibration result (its ``camera``). With it, edges are fitted as
                straight lines in undistorted coordinates (a second, refining pass after a
                first calibration).
            source: recorded in the result (a file name, a bag message).

        Returns:
            :class:`Detections` with ids, corners (N, 4, 2), centers (N, 2) and
            per-point sigmas, in pixels.
        """
        frame = self._read(image)
        if self._candidates is None:     # a chessboard or a circle grid: points only
            return self._detect_points(frame, camera, source)
        # 1. candidates: quads and ids of the board's markers (in a stream, the markers the
        # frames before predict first: :mod:`.stream_predict`)
        clipped = is_clipped(frame.gray8)
        stream = self._stream
        if stream is None:
            return self._markers(frame, *self._candidates.find(frame.gray8, frame.lin,
                                                                clipped=clipped),
                                 clipped, camera, source)
        found = stream.find(frame.gray8, frame.lin, clipped=clipped)
        pools = self.snapshot() if stream.predicted else None
        dets = self._markers(frame, *found, clipped, camera, source)
        if pools is not None and stream.fell_short(dets.ids):
            # the prediction did not hold: this frame searched whole, its pools' evidence once
            stream.full_search()
            self._lens_pool.restore(pools[0])
            self._tone_pool.restore(pools[1])
            dets = self._markers(frame, *self._candidates.find(frame.gray8, frame.lin,
                                                                clipped=clipped),
                                 clipped, camera, source)
        stream.update(dets.ids, dets.corners_px)
        return dets

    def _markers(self, frame: _Frame, quads: np.ndarray, ids: np.ndarray, clipped: bool,
                 camera: CameraModel | HasCamera | None, source: str) -> Detections:
        """Stages 2-5 of :meth:`detect` on the candidates, quads (N, 4, 2) and ids (N,)."""
        if len(ids) == 0:
            return replace(Detections.empty(frame.size, source), sharpness=frame.sharpness)
        quads, ids, dark = self._of_polarity(frame.lin, quads, ids)
        # 2. exposure
        exposure = self._exposure(frame, quads, clipped)
        # 3. edges: sub-pixel corners (and the frame's tone curve and lens)
        edges = _Edges(frame, _Markers(ids, np.asarray(quads, dtype=np.float64),
                                       np.full((len(ids), 4), np.nan)), dark,
                       known_lens(camera) if camera is not None else None)
        if self.config.refine_edges and len(ids):
            edges = self._fit_edges(edges, quads, exposure)
        frame = edges.frame
        # 4. verification, and a clipped frame's missing markers looked for on the grid
        markers, rejected = self._verify(frame.lin, edges, exposure.clipped)
        if edges.lens is not None and self.config.refine_edges:
            markers = self._rim(frame.lin, markers, edges, exposure.clipped)
        if (exposure.clipped and self.config.grid_search and self.config.refine_edges
                and self.board.board_type == "marker_grid"):
            markers = self._grid_search(frame.lin, markers, rejected, edges)
        # 5. centres, and the view's edge shift removed from the corners
        return self._finish(frame, markers, edges,
                            exposure.clipped and exposure.ink >= _PLACE_ABOVE, source)

    def _read(self, image: np.ndarray) -> _Frame:
        """The image as the stages read it, through the configured or pooled tone curve."""
        gray = to_gray(image)
        gray8 = to_gray8(gray)
        gamma = self._fixed_gamma(gray.dtype)
        probing = gamma == 0 and not self._tone_pool.settled
        curve = ToneCurve("power", gamma) if gamma > 0 else self._tone_pool.estimate().curve
        return _Frame(gray, gray8, curve.linearise(gray), curve, probing, sharpness(gray8))

    def _detect_points(self, frame: _Frame, camera: CameraModel | HasCamera | None,
                       source: str) -> Detections:
        """A chessboard's or circle grid's points. No marker borders to estimate the tone
        curve from: the configured curve or the pool's (gamma 2.2 until markers say
        otherwise)."""
        if self.board.circles is not None:
            pids, pts, psig = detect_circles(
                frame.gray8, frame.lin, self.board,
                known_lens(camera) if camera is not None else None)
        else:
            pids, pts, psig = detect_chessboard(frame.gray8, frame.lin, self.board)
        return replace(Detections.empty(frame.size, source), sharpness=frame.sharpness,
                       point_ids=pids, points_px=pts, point_sigma_px=psig)

    def _of_polarity(self, lin: np.ndarray, quads: np.ndarray, ids: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The candidates whose border has the board's polarity, and (N,) bool, dark border."""
        dark = border_is_dark(lin, quads, self.board.bits)
        if self.board.polarity != "any":
            keep = dark == self._dark(ids)
            quads, ids, dark = quads[keep], ids[keep], dark[keep]
        return quads, ids, dark

    def _exposure(self, frame: _Frame, quads: np.ndarray, clipped: bool) -> _Exposure:
        """How dark the ink of a frame (``clipped`` or not) reads, and whether the fit censors."""
        # censoring saturated samples keeps a clipped edge's fit consistent while its
        # transition shows; once the ink nears saturation the clipped plateau's edge is
        # steadier. A frame clipped in part is censored too (only its saturated sides)
        saturated = clipped or saturates(frame.gray8)
        ink = dark_level(frame.lin, quads, self.board.bits) if saturated else 0.0
        return _Exposure(clipped, ink,
                         self.config.censor_clipped and saturated and ink < _CENSOR_BELOW,
                         not saturated)

    def _fit_edges(self, edges: _Edges, quads: np.ndarray, exposure: _Exposure) -> _Edges:
        """The edge fit of the candidates (``edges``: as found, with the given lens); a
        probing frame is fitted again through a better tone curve when its fit shows one."""
        frame, ids, dark, lens = edges.frame, edges.markers.ids, edges.dark, edges.lens
        lens_state = self._lens_pool.snapshot()
        probe = self._probe(frame.curve) if frame.probing else None
        censor_at = (censor_level(frame.curve, frame.gray, frame.gray8) if exposure.censor
                     else None)
        fit = self._refine(frame.lin, quads, dark, ids, lens, probe, censor_at, exposure.light)
        if probe is not None:
            probe.commit()
            better = self._tone_pool.estimate().curve
            if differs(better, frame.curve):
                # this frame's edges again through the better curve (its lens
                # evidence replaces, not joins, that of the first fit)
                self._lens_pool.restore(lens_state)
                frame = replace(frame, curve=better, lin=better.linearise(frame.gray))
                censor_at = (censor_level(better, frame.gray, frame.gray8) if exposure.censor
                             else None)
                fit = self._refine(frame.lin, quads, dark, ids, lens, None, censor_at,
                                   exposure.light)
        # a lens estimated here bends the fitted sides; it moves the centres too once it is
        # known better than "no distortion" (|lam| above its standard deviation)
        if isinstance(fit.lens, DivisionLens) and fit.lens.significance >= 1.0:
            lens = fit.lens
        keep = fit.ok & same_edges(fit.corners_px, quads)
        # a marker cut by the image edge has no corner there, only the edge
        keep &= _clear_of_edge(fit.corners_px, *frame.size, 0.5)
        markers = _Markers(ids[keep], np.asarray(fit.corners_px[keep], dtype=np.float64),
                           fit.corner_sigma_px[keep])
        return _Edges(frame, markers, dark[keep], lens, fit.lens, censor_at, exposure.light)

    def _verify(self, lin: np.ndarray, edges: _Edges, clipped: bool
                ) -> tuple[_Markers, tuple[np.ndarray, np.ndarray]]:
        """The markers whose code, neighbours and sides check out, and the rest's corners
        (R, 4, 2) and ids (R,). A marker that fails in the image is read again through the
        edge fit's lens: far out in a strong lens a marker's homography no longer predicts
        its neighbours nor its border's modules, in straightened pixels it does."""
        markers, ids, check = edges.markers, edges.markers.ids, self._checks(clipped)
        corners = markers.corners_px
        ok = checks_pass(lin, corners, edges.dark, ids, self.board, **check)
        if edges.lens is not None and not ok.all():
            ok |= checks_pass(lin, corners, edges.dark, ids, self.board, lens=edges.lens, **check)
        return (_Markers(ids[ok], corners[ok], markers.sigma_px[ok]),
                (corners[~ok], ids[~ok]))

    def _checks(self, clipped: bool) -> dict[str, Any]:
        """This detector's settings of :func:`checks_pass`."""
        c = self.config
        return dict(max_bit_errors=c.max_bit_errors, tolerance=c.neighbour_tolerance,
                    max_bit_errors_isolated=c.max_bit_errors_isolated, grow_to=self._grow_to,
                    clipped=clipped)

    def _rim(self, lin: np.ndarray, markers: _Markers, edges: _Edges, clipped: bool
             ) -> _Markers:
        """The quad finder's near misses that the lens bends, read through it (:mod:`.rim`)
        and verified together with the markers already found."""
        assert self._candidates is not None
        n, lens, cat = len(markers.ids), edges.lens, np.concatenate

        def keep(c: np.ndarray, i: np.ndarray) -> np.ndarray:
            ids = cat([markers.ids, i])
            return checks_pass(lin, cat([markers.corners_px, c]), self._dark(ids), ids,
                               self.board, lens=lens, **self._checks(clipped))[n:]
        found = read_through_lens(
            lin, lens, self._candidates.near_misses, markers.ids, self._candidates.patterns,
            self.board.bits, lambda q, i: self._refine(lin, q, self._dark(i), i, lens, None,
                                                        edges.censor_at, edges.light,
                                                        pool=False), keep)
        return _Markers(*(cat([a, b]) for a, b in zip(markers, found, strict=True)))

    def _grid_search(self, lin: np.ndarray, markers: _Markers,
                     rejected: tuple[np.ndarray, np.ndarray], edges: _Edges) -> _Markers:
        """Blooming hides most small markers from the quad finder: look where the verified
        ones say the others are (docs/tone.md, "Clipped frames")."""
        assert self._candidates is not None
        return _Markers(*grow(
            lin, markers.ids, markers.corners_px, markers.sigma_px, self.board,
            self._candidates.clipped_patterns,
            lambda q, i: self._refine(lin, q, self._dark(i), i, edges.lens, None,
                                      edges.censor_at, edges.light, pool=False),
            min_side_px=self.config.min_side_px,
            tolerance=self.config.neighbour_tolerance, hints=rejected))

    def _finish(self, frame: _Frame, markers: _Markers, edges: _Edges, place_sides: bool,
                source: str) -> Detections:
        """Centres, the view's edge shift removed from the corners, and the result."""
        ids, corners, sigma = markers
        centers, center_sigma = diagonal_centers(corners, sigma, edges.lens)
        shift = float("nan")
        # (a ChArUco board's markers are not on one pitch: its corners come from the saddles)
        if (self.config.edge_shift and self.config.refine_edges
                and self.board.board_type == "marker_grid"):
            corners, shift = remove_view_shift(
                corners, centers, ids, self.board, ~self._dark(ids),
                edges.lens if edges.lens is not None else edges.fit_lens,
                place_sides=place_sides)
        order = np.argsort(ids)
        dets = Detections(ids[order], corners[order], centers[order], frame.size,
                          sigma[order], center_sigma[order], frame.sharpness, source,
                          edge_shift_px=shift)
        if self.board.board_type == "charuco":
            return dets.with_points(*charuco_corners(frame.lin, self.board, dets.ids,
                                                     dets.corners_px))
        return dets


def detect(image: np.ndarray, board: Board, *, config: DetectorConfig | None = None,
           camera: CameraModel | HasCamera | None = None, source: str = "") -> Detections:
    """Detect ``board``'s markers in ``image`` (see :meth:`Detector.detect`)."""
    return Detector(board, config).detect(image, camera, source=source)
