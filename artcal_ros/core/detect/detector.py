"""The detection pipeline: candidate quads, board-aware decoding, sub-pixel corners and centers.

A chessboard goes to :mod:`artcal_ros.core.detect.chessboard` instead (no markers), a
circle grid to :mod:`artcal_ros.core.detect.circles`; a
ChArUco board runs the marker pipeline below with its markers, then
:mod:`artcal_ros.core.detect.charuco` measures its corners from them.

Pipeline for one image:

1. Candidate quads and ids from OpenCV's ArUco detector (both polarities when the
   board has white-on-black markers), run on an 8-bit, contrast-stretched copy.
   The quads it found but could not read are decoded again against the board's
   own patterns, blur-aware (:mod:`artcal_ros.core.detect.candidates`,
   :mod:`artcal_ros.core.detect.decode`).
2. Only ids on the configured board survive; duplicated ids are dropped.
3. Each quad is refined from its border edges in linear intensity
   (:mod:`artcal_ros.core.detect.edges`, :mod:`artcal_ros.core.detect.step_model`):
   a blurred-step model fitted to the raw pixels across every side, sides bent
   by the lens (given, or estimated from the edges and pooled over frames),
   intersected into corners.
4. Verification (:mod:`artcal_ros.core.detect.verify`): the border's polarity
   must match the board, the code re-read on the refined quad must match the id
   (at most 2 wrong cells; none for a marker without neighbours), and the marker
   must sit where its image neighbours say it should on the board. A wrong id
   cannot reach the solver. In an over-exposed frame the verified markers then
   place the missing ones on the grid, and those whose code reads there are fitted
   and checked too (:mod:`artcal_ros.core.detect.grid_search`).
5. Centers (:mod:`artcal_ros.core.detect.centers`): the intersection of the
   refined quad's diagonals (exact under a pinhole projection). With a lens
   (given, or estimated and well determined) the corners are mapped to
   undistorted pixels first and the center mapped
   back; without one, the diagonals of the distorted quad are used, which is
   off by second-order terms of the distortion across the marker (a few
   hundredths of a pixel for 20 - 40 px markers near the corners of a strongly
   distorted webcam image).

Pixel convention: OpenCV's, the center of the top-left pixel is (0, 0).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.camera import CameraModel, HasCamera
from artcal_ros.core.detect.candidates import CandidateFinder
from artcal_ros.core.detect.centers import diagonal_centers
from artcal_ros.core.detect.charuco import charuco_corners
from artcal_ros.core.detect.chessboard import detect_chessboard
from artcal_ros.core.detect.circles import detect_circles
from artcal_ros.core.detect.edge_shift import (
    compensate,
    neighbourhood_shift_px,
    robust_shift_px,
    toward_neighbourhood,
)
from artcal_ros.core.detect.edges import EdgeFit, ProbeFit, refine_quads, same_edges
from artcal_ros.core.detect.exposure import censor_level, dark_level, is_clipped, saturates
from artcal_ros.core.detect.grid_search import grow
from artcal_ros.core.detect.image import to_gray, to_gray8
from artcal_ros.core.detect.lens import DivisionLens, Lens, LensPool, known_lens
from artcal_ros.core.detect.patterns import inner_border_cells, outer_neighbours
from artcal_ros.core.detect.sampling import border_is_dark
from artcal_ros.core.detect.tone import (
    CANDIDATES,
    ToneCurve,
    ToneEstimate,
    TonePool,
    differs,
    probe_costs,
)
from artcal_ros.core.detect.verify import code_errors, neighbour_support, sides_are_edges
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import DetectionError

__all__ = ["Detector", "DetectorConfig", "detect"]


@dataclass(frozen=True)
class DetectorConfig:
    """Tuning of :class:`Detector`; the defaults suit printed boards and ordinary cameras.

    Attributes:
        gamma: exponent that maps encoded grey values to linear light
            (``linear = (v / full_scale) ** gamma``): 2.2 for sRGB-like 8-bit
            images, 1.0 for linear (e.g. raw 16-bit) data; 0 (the default)
            estimates the tone curve from the images' edges
            (:mod:`~artcal_ros.core.detect.tone`), pooled over the frames a
            :class:`Detector` sees.
        gamma_16bit: the same for 16-bit images (None: use ``gamma``).
        refine_edges: False keeps the quad finder's corners (for comparisons only).
        margin_px: edge profiles closer than this to a corner are skipped.
        curve_min_px: image sides at least this long are fitted as parabolas
            (lens distortion bends them) when no camera model is given.
        estimate_lens: without a camera model, estimate a one-parameter division
            lens from those parabolas (plumb lines) and bend every side by it.
        max_bit_errors: most code cells (of bits^2) that may disagree with the
            id when a marker is supported by a neighbour.
        max_bit_errors_isolated: the same for a marker no neighbour can vouch
            for; None rejects isolated markers outright.
        neighbour_tolerance: how far (in marker sides) a neighbour may sit from
            where this marker's own homography puts it.
        min_side_px: quads with a shorter side are ignored.
        code_rows: code rows behind the border modelled by the edge fit (1 or 2).
        decode_rejected: decode the quads OpenCV could not read against the
            board's own patterns (recovers markers under blur and clipping).
        pool_lens: pool the lens estimate over the frames a :class:`Detector` sees
            (one camera per detector; :meth:`Detector.reset_lens` forgets).
        adaptive_window_max: largest adaptive-threshold window of the quad finder.
        edge_shift: measure each view's edge shift from its markers' size against
            their pitch and remove it from the corners
            (:mod:`~artcal_ros.core.detect.edge_shift`); in a frame so over-exposed that
            the ink reads above 0.35 of saturation, and whose sides scatter, also move
            the corners toward the sides placed by the neighbours' centres
            (``toward_neighbourhood``).
        censor_clipped: in an over-exposed frame whose ink is still below 0.85 of
            saturation, fit the edges with the saturated pixels as censored data (they
            only say the light there reached full scale); see docs/tone.md.
        grid_search: in an over-exposed frame, look for the markers the quad finder
            missed where the verified ones place them on the board's grid
            (:mod:`~artcal_ros.core.detect.grid_search`; marker grids only).
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
    edge_shift: bool = True
    censor_clipped: bool = True
    grid_search: bool = True

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


# a view's edge shift is removed only beyond this over the markers read plus 2 sigma, px:
# against truth the shift read from the centres errs by up to 0.011 px in close views of
# 13 - 25 large markers (more than its sigma says; the centres' own errors) and by about
# 0.001 px in views of 170, where a clean frame's true shift of 0.003 - 0.01 px is worth
# removing
_SHIFT_ERROR_PX = 0.3
# a clipped frame's saturated samples are censored in the edge fit while its ink is
# darker than this share of saturation (the paper then up to about 14 times over, for a
# print of ordinary contrast). Set on the exposure sweep (bench.exposure): censoring
# halves the centres' error or better where the ink reads 0.1 - 0.84, and makes it
# worse at 0.9 - 0.93, where only a sliver of each edge's transition is left unclipped
_CENSOR_BELOW = 0.85
# a clipped frame's corners are moved toward the sides its neighbours place only once the
# ink itself reads above this share of saturation (the paper about 5 times over or more),
# where blooming eats into the edges. Below it the censored fit holds the edges, and the
# scatter of the sides is the frame's noise: on realistic frames (JPEG, defocus, ink at
# 0.1) the move made corners worse (seed 7340's 20-view calibration 0.031 -> 0.052 px)
_PLACE_ABOVE = 0.35

# most pilot sides a frame's tone probe re-fits per candidate curve
_PROBE_SIDES = 16


class _ToneProbe:
    """Keeps the last fit :func:`refine_quads` offers; :meth:`commit` probes it into the pool."""

    def __init__(self, pool: TonePool, curve: ToneCurve) -> None:
        self.pool, self.curve = pool, curve
        self.last: ProbeFit | None = None

    def __call__(self, fit: ProbeFit) -> None:
        self.last = fit

    def commit(self) -> None:
        """The candidate curves' costs on the kept fit's sides, added to the pool."""
        if self.last is None:
            return
        fit, self.last = self.last, None
        pick = np.linspace(0, len(fit.sides) - 1, min(len(fit.sides), _PROBE_SIDES))
        sides = fit.sides[pick.astype(int)]
        fit_values, values = fit.subset(sides, copies=len(CANDIDATES))
        costs, sound = probe_costs(fit_values, values, sides, self.curve, fit.coef, fit.blur)
        counts = np.bincount(np.asarray(fit.samples.side), minlength=len(fit.coef))[sides]
        self.pool.add(costs, int(counts[sound].sum()), int(sound.sum()))


def _clear_of_edge(corners: np.ndarray, w: int, h: int, clear: float) -> np.ndarray:
    """(M,) bool: all four corners at least ``clear`` pixels inside the image."""
    x, y = corners[..., 0], corners[..., 1]
    inside = (x >= clear) & (x <= w - 1 - clear) & (y >= clear) & (y <= h - 1 - clear)
    return np.asarray(inside.all(axis=1) & np.isfinite(corners).all(axis=(1, 2)))


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
                decode_rejected=self.config.decode_rejected,
                min_side_px=self.config.min_side_px)
        self._lens_pool = LensPool()
        self._tone_pool = TonePool()
        # ChArUco markers sit sqrt(2) squares apart at the closest (see neighbour_support)
        self._grow_to: float | None = None
        if board.board_type == "charuco":
            self._grow_to = 0.45 * np.sqrt(2.0) * board.square_length / board.marker_length
        # quiet zone around a marker's border, in modules (mixed boards: half the gap)
        self._quiet_modules = board.quiet_zone_m / board.module_length if board.bits else 0.0

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

    def _probe(self, curve: ToneCurve) -> _ToneProbe:
        """A ``tone_probe`` for :func:`refine_quads` that adds a frame to the pool."""
        return _ToneProbe(self._tone_pool, curve)

    def _refine(self, lin: np.ndarray, quads: np.ndarray, dark: np.ndarray, ids: np.ndarray,
                lens: Lens | None, probe: _ToneProbe | None, censor_at: float | None = None,
                pool: bool = True) -> EdgeFit:
        """The edge fit of every quad (:func:`refine_quads` with this detector's settings;
        ``censor_at``: samples at or above this linear level are censored; ``pool``: the
        frame's lens evidence joins the pool)."""
        return refine_quads(lin, quads, dark, self.board.bits, margin_px=self.config.margin_px,
                            curve_min_px=self.config.curve_min_px, passes=1,
                            allow_curvature=lens is None and self.config.estimate_lens,
                            lens=lens,
                            inner_same=inner_border_cells(self.board, ids,
                                                          rows=self.config.code_rows),
                            quiet_modules=self._quiet_modules,
                            outer_same=self._outer_edges(ids),
                            beyond_modules=self._quiet_modules,
                            lens_pool=self._lens_pool if self.config.pool_lens and pool
                            else None,
                            tone_probe=probe,
                            censor_at=censor_at)

    def _dark(self, ids: np.ndarray) -> np.ndarray:
        """(N,) bool: the board prints these markers with a dark border."""
        return np.array([not self.board.is_inverted(int(i)) for i in ids], bool)

    def _remove_edge_shift(self, corners: np.ndarray, centers: np.ndarray, ids: np.ndarray,
                           lens: Lens | None, place_sides: bool = False
                           ) -> tuple[np.ndarray, float]:
        """The corners with the view's edge shift removed, and the shift (NaN: unknown), px.

        ``place_sides``: a far over-exposed frame; its corners are also moved toward the
        sides its neighbours place (:func:`toward_neighbourhood`).

        Measured and removed in undistorted pixels when a lens is known, so the
        lens's change of scale between neighbours does not read as a shift.
        """
        m = len(ids)
        q, c = corners, centers
        if lens is not None and m:
            q = lens.undistort(corners.reshape(-1, 2)).reshape(m, 4, 2)
            c = lens.undistort(centers)
        # each marker's shift against the centres around it (they do not move with it)
        marker_shift = neighbourhood_shift_px(ids, q, c, self.board)
        # light spreading into dark grows a white-bordered marker and shrinks a black one:
        # on a mixed board each polarity has its own shift (reported: the black ones')
        inverted = ~self._dark(ids)
        shift, largest = float("nan"), 0.0
        q_u, q = q, q.copy()
        for group in (~inverted, inverted):
            if not group.any():
                continue
            d, d_sd = robust_shift_px(marker_shift[group])
            if not np.isfinite(d_sd):
                continue
            n_read = int(np.isfinite(marker_shift[group]).sum())
            if abs(d) <= _SHIFT_ERROR_PX / n_read + 2.0 * d_sd:
                d = 0.0     # not told apart from no shift: removing it would add error
            # every side moves back along its normal (the centres were measured already)
            q[group] = compensate(q[group], d)
            largest = max(largest, abs(d))
            if not np.isfinite(shift):
                shift = d
        if not np.isfinite(shift):
            return corners, float("nan")
        if lens is not None:
            # the move, mapped back (the round trip of a point far out in a strong lens
            # need not return it exactly: only the difference is taken)
            moved = lens.distort(q.reshape(-1, 2)) - lens.distort(q_u.reshape(-1, 2))
            q = corners + moved.reshape(m, 4, 2)
            # a move the lens magnified beyond any shift's size is not one (a fold)
            wild = ~(np.linalg.norm(q - corners, axis=-1) <= 4.0 * largest + 0.05).all(axis=1)
            q[wild] = corners[wild]
        if place_sides:
            q = toward_neighbourhood(ids, corners, q, centers, self.board)
        return q, shift

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
        gray = to_gray(image)
        h, w = gray.shape
        gray8 = to_gray8(gray)
        sharpness = float(cv2.Laplacian(gray8, cv2.CV_32F).var())
        gamma = self._fixed_gamma(gray.dtype)
        probing = gamma == 0 and not self._tone_pool.settled
        curve = ToneCurve("power", gamma) if gamma > 0 else self._tone_pool.estimate().curve
        lin = curve.linearise(gray)
        # a chessboard has no marker borders to estimate the tone curve from: the
        # configured curve or the pool's (gamma 2.2 until markers say otherwise)
        if self._candidates is None:     # a chessboard or a circle grid: points only
            if self.board.circles is not None:
                pids, pts, psig = detect_circles(
                    gray8, lin, self.board, known_lens(camera) if camera is not None else None)
            else:
                pids, pts, psig = detect_chessboard(gray8, lin, self.board)
            return replace(Detections.empty((w, h), source), sharpness=sharpness,
                           point_ids=pids, points_px=pts, point_sigma_px=psig)
        bits = self.board.bits
        quads, ids = self._candidates.find(gray8, lin)
        if len(ids) == 0:
            return replace(Detections.empty((w, h), source), sharpness=sharpness)

        dark = border_is_dark(lin, quads, bits)
        if self.board.polarity != "any":
            keep = dark == self._dark(ids)
            quads, ids, dark = quads[keep], ids[keep], dark[keep]

        clipped = is_clipped(gray8)
        # censoring the saturated samples makes a clipped edge's fit consistent while its
        # transition still shows; once the ink itself nears saturation only a sliver
        # of it does, and the edge of the clipped plateau is the steadier measure. A
        # frame clipped in part (a brighter patch of light) is censored too: only the
        # sides with saturated samples are fitted differently
        saturated = clipped or saturates(gray8)
        ink = dark_level(lin, quads, bits) if saturated else 0.0
        censor = self.config.censor_clipped and saturated and ink < _CENSOR_BELOW
        lens: Lens | None = (
            known_lens(camera) if camera is not None else None)
        fit_lens: Lens | None = None
        censor_at: float | None = None
        corners: np.ndarray
        if self.config.refine_edges and len(ids):
            lens_state = self._lens_pool.snapshot()
            probe = self._probe(curve) if probing else None
            censor_at = censor_level(curve, gray, gray8) if censor else None
            fit = self._refine(lin, quads, dark, ids, lens, probe, censor_at)
            if probe is not None:
                probe.commit()
                better = self._tone_pool.estimate().curve
                if differs(better, curve):
                    # this frame's edges again through the better curve (its lens
                    # evidence replaces, not joins, that of the first fit)
                    self._lens_pool.restore(lens_state)
                    curve, lin = better, better.linearise(gray)
                    censor_at = censor_level(curve, gray, gray8) if censor else None
                    fit = self._refine(lin, quads, dark, ids, lens, None, censor_at)
            # a lens estimated from this frame's edges bends the fitted sides; it moves
            # the centers too once it is determined better than "no distortion" is
            # (|lam| above its standard deviation; a noisier one would add more error
            # to them than the distortion it removes)
            fit_lens = fit.lens
            if isinstance(fit.lens, DivisionLens) and fit.lens.significance >= 1.0:
                lens = fit.lens
            keep = fit.ok & same_edges(fit.corners_px, quads)
            # a marker cut by the image edge has no corner there, only the edge
            keep &= _clear_of_edge(fit.corners_px, w, h, 0.5)
            corners, sigma = fit.corners_px[keep], fit.corner_sigma_px[keep]
            ids, dark = ids[keep], dark[keep]
        else:
            corners, sigma = quads, np.full((len(ids), 4), np.nan)
        corners = np.asarray(corners, dtype=np.float64)

        errors = code_errors(lin, corners, dark, ids, self.board)
        support = neighbour_support(corners, ids, self.board, self.config.neighbour_tolerance,
                                    self._grow_to)
        ok = (errors <= self.config.max_bit_errors) & (support > 0)
        if self.config.max_bit_errors_isolated is not None:
            ok |= (support == 0) & (errors <= self.config.max_bit_errors_isolated)
        ok &= support >= 0
        ok &= sides_are_edges(lin, corners, dark, bits, clipped=clipped)
        rejected = (corners[~ok], ids[~ok])
        corners, sigma, ids = corners[ok], sigma[ok], ids[ok]
        if (clipped and self.config.grid_search and self.config.refine_edges
                and self.board.board_type == "marker_grid"):
            # blooming hides most small markers from the quad finder: look where the
            # verified ones say the others are (docs/tone.md, "Clipped frames")
            ids, corners, sigma = grow(
                lin, ids, corners, sigma, self.board, self._candidates.clipped_patterns,
                lambda q, i: self._refine(lin, q, self._dark(i), i, lens, None, censor_at,
                                          pool=False),
                min_side_px=self.config.min_side_px,
                tolerance=self.config.neighbour_tolerance, hints=rejected)

        centers, center_sigma = diagonal_centers(corners, sigma, lens)
        shift = float("nan")
        # (a ChArUco board's markers are not on one pitch: its corners come from the saddles)
        if (self.config.edge_shift and self.config.refine_edges
                and self.board.board_type == "marker_grid"):
            corners, shift = self._remove_edge_shift(corners, centers, ids,
                                                     lens if lens is not None else fit_lens,
                                                     clipped and ink >= _PLACE_ABOVE)
        order = np.argsort(ids)
        dets = Detections(ids[order], corners[order], centers[order], (w, h),
                          sigma[order], center_sigma[order], sharpness, source,
                          edge_shift_px=shift)
        if self.board.board_type == "charuco":
            return dets.with_points(*charuco_corners(lin, self.board, dets.ids, dets.corners_px))
        return dets


def detect(image: np.ndarray, board: Board, *, config: DetectorConfig | None = None,
           camera: CameraModel | HasCamera | None = None, source: str = "") -> Detections:
    """Detect ``board``'s markers in ``image`` (see :meth:`Detector.detect`)."""
    return Detector(board, config).detect(image, camera, source=source)
