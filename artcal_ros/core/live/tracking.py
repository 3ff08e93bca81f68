"""Markers followed from frame to frame: approximate quads at a camera's frame rate.

Precise detection (:class:`~artcal_ros.core.detect.Detector`) costs a few hundred
milliseconds a 1080p frame on a small machine, far more than a 30 Hz camera leaves. A
live view needs every frame, not full precision: the overlay is drawn at most
``overlay.max_width`` wide and the choice of which frames to keep as views needs only
rough marker positions. :class:`MarkerTracker` gives those in a few milliseconds:

- it holds the markers of the last precise detection (:meth:`MarkerTracker.seed`),
  carried forward to the newest frame with pyramidal Lucas-Kanade optical flow on a
  downscaled grey copy. Only the marker centres are followed: a window around a centre
  sees the whole marker and deforms symmetrically, where one around a corner drifts along
  the border as the board turns (an order of magnitude more than a centre). The corners
  come from a homography fitted to the board positions of the marker's neighbours and
  their tracked centres;
- a marker is dropped as soon as its centre is lost, leaves the image, moves unlike its
  board neighbours (a slip onto the next marker of the repeating board moves it a whole
  pitch more than they do), or its neighbourhood no longer fits one homography. No id is
  ever read here: every id was decoded and verified by the precise detector, so a board
  leaving the view loses its markers rather than renaming them;
- a seed comes from an older frame (the precise detector is slower than the stream); the
  tracker keeps the last ``history`` downscaled frames and carries the seed through them
  to the newest one.

The points it returns are approximate (the flow is tracked at the overlay's scale, about a
pixel there), with NaN sigmas: they are for display and view selection, never for a solve.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass, replace

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.linalg import nanmedian_rows
from artcal_ros.core.detections import Detections
from artcal_ros.core.homography import apply_h

__all__ = ["MarkerTracker", "TrackerConfig"]


@dataclass(frozen=True)
class TrackerConfig:
    """Tuning of :class:`MarkerTracker`.

    Attributes:
        max_width: frames are tracked downscaled to at most this width, pixels.
        history: downscaled frames kept to carry an older seed forward.
        window_px: Lucas-Kanade window side at the tracking scale, pixels.
        levels: pyramid levels above the base image.
        coarse_levels: pyramid levels of the coarse search that starts a fresh seed.
        reach: neighbours up to this many board cells away vouch for a marker and fit its
            homography.
        max_jump: largest difference between a marker's motion and the median motion of
            its neighbours, as a fraction of the marker pitch in the image.
        max_residual: largest misfit of a neighbourhood's homography at its centres, as a
            fraction of the pitch.
        max_wrong_modules: most modules (border and code, read at the tracked quad) that
            may disagree with the marker's printed pattern.
    """

    max_width: int = 960
    history: int = 45
    window_px: int = 31
    levels: int = 2
    coarse_levels: int = 4
    reach: int = 2
    max_jump: float = 0.3
    max_residual: float = 0.1
    max_wrong_modules: int = 4


@dataclass(frozen=True)
class _Frame:
    index: int
    gray: np.ndarray      # (h, w) uint8 at the tracking scale
    quarter: np.ndarray   # (h/4, w/4) uint8, for the coarse search
    shift: np.ndarray     # (2,) median motion of the tracked centres into this frame


@dataclass(frozen=True)
class _Tracks:
    """Marker centres followed frame to frame from the last seed (tracking scale)."""

    frame: _Frame              # the frame the centres are in
    ids: np.ndarray            # (M,) int64
    centers: np.ndarray        # (M, 2) float32
    velocity: np.ndarray       # (M, 2) float32, last motion of each centre


def _quarter(gray: np.ndarray) -> np.ndarray:
    """A quarter-size copy (each side), for the coarse search."""
    h, w = gray.shape
    return cv2.resize(gray, (max(8, w // 4), max(8, h // 4)), interpolation=cv2.INTER_AREA)


def _small_gray(image: np.ndarray, max_width: int) -> tuple[np.ndarray, float]:
    """(h, w) uint8 grey copy at most ``max_width`` wide, and its scale (small / full)."""
    img = image
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY)
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    scale = 1.0
    if img.shape[1] > max_width:
        scale = max_width / img.shape[1]
        size = (max_width, max(1, round(img.shape[0] * scale)))
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    return np.ascontiguousarray(img), scale


def _local_homographies(src: np.ndarray, dst: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(M, 3, 3) homographies, each fitted to the valid ones of its K point pairs.

    Linear least squares with h33 = 1 (the points are centred on the marker, where the
    homography cannot vanish), all M 8 x 8 normal equations solved at once.

    Args:
        src, dst: (M, K, 2) point pairs, already centred and scaled near unit size.
        valid: (M, K) bool, pairs to use (rows with fewer than 4 give garbage).
    """
    m = valid.shape[0]
    x, y = src[..., 0], src[..., 1]
    u, v = dst[..., 0], dst[..., 1]
    zero, one = np.zeros_like(x), np.ones_like(x)
    rows_u = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y], axis=-1)
    rows_v = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y], axis=-1)
    w = valid.astype(np.float64)[..., None]
    a = np.concatenate([rows_u * w, rows_v * w], axis=1)          # (M, 2K, 8)
    rhs = np.concatenate([u * w[..., 0], v * w[..., 0]], axis=1)  # (M, 2K)
    at = a.transpose(0, 2, 1)
    ata = at @ a + 1e-9 * np.eye(8)
    atb = (at @ rhs[..., None])[..., 0]
    h = np.linalg.solve(ata, atb[..., None])[..., 0]
    return np.concatenate([h, np.ones((m, 1))], axis=1).reshape(m, 3, 3)


class MarkerTracker:
    """Approximate marker quads for every frame of one camera's stream (thread-safe).

    :meth:`track` is called with each new frame, :meth:`seed` with precise detections of an
    earlier frame (by the index :meth:`track` gave it), possibly from another thread.
    Centres are matched from each frame to the next; the small drift that accumulates is
    reset by every seed.

    Args:
        board: the board whose markers are followed (their neighbours vouch for them).
        config: tuning, see :class:`TrackerConfig`.
    """

    def __init__(self, board: Board, config: TrackerConfig | None = None) -> None:
        self.board = board
        self.config = config or TrackerConfig()
        self._lock = threading.Lock()
        self._frames: deque[_Frame] = deque(maxlen=self.config.history)
        self._next_index = 0
        self._size: tuple[int, int] | None = None
        self._scale = 1.0
        self._tracks: _Tracks | None = None
        # board cells of every id, and each marker's corners and centre in pitch units
        reach = self.config.reach
        self._offsets = np.array([(dr, dc) for dr in range(-reach, reach + 1)
                                  for dc in range(-reach, reach + 1)])
        self._object_corners = board.object_corners()[:, :, :2] / board.pitch
        self._object_centers = board.object_centers()[:, :2] / board.pitch
        # every module centre of every marker, relative to its centre, in pitch units, and
        # whether it is printed white
        n = board.bits + 2
        f = (np.arange(n) + 0.5) / n
        tl, tr, bl = (self._object_corners[:, k] for k in (0, 1, 3))
        grid = (tl[:, None, None] + f[None, None, :, None] * (tr - tl)[:, None, None]
                + f[None, :, None, None] * (bl - tl)[:, None, None])      # (N, n, n, 2)
        # (a chessboard has no markers: nothing is tracked on it)
        self._modules = (grid - self._object_centers[:, None, None]).reshape(len(tl), n * n, 2)
        self._white = (np.stack([board.marker_modules(int(i)) for i in board.ids])
                       .reshape(len(tl), n * n) if len(tl) else np.zeros((0, n * n), bool))

    def reset(self) -> None:
        """Forget every frame and marker (another camera, or a new image size)."""
        with self._lock:
            self._clear()

    def _clear(self) -> None:
        self._frames.clear()
        self._size = None
        self._tracks = None

    def _step(self, tracks: _Tracks, frame: _Frame) -> _Tracks:
        """The markers carried into ``frame`` (those that survive every check).

        ``frame.shift`` is its median motion since the previous one, where known (else 0).
        """
        if len(tracks.ids) == 0:
            return replace(tracks, frame=frame)
        shift = frame.shift
        cfg = self.config
        # The search starts where constant motion puts each centre (or, for a fresh seed,
        # the motion the frame is known to have had), so a fast sweep does not alias onto
        # the next marker of the repeating board.
        fresh = not np.any(tracks.velocity)
        own = tracks.velocity - np.median(tracks.velocity, axis=0)
        prior = shift if fresh else np.median(tracks.velocity, axis=0)
        shift = self._coarse_shift(tracks, frame, prior)
        image = frame.gray
        guess = (tracks.centers + own + shift).reshape(-1, 1, 2).astype(np.float32)
        moved, status, _ = cv2.calcOpticalFlowPyrLK(
            tracks.frame.gray, image, tracks.centers.reshape(-1, 1, 2), guess,
            winSize=(cfg.window_px, cfg.window_px), maxLevel=cfg.levels,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.03),
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
        moved = moved.reshape(-1, 2)
        h, w = image.shape
        keep = ((status.ravel() == 1) & (moved[:, 0] >= 0) & (moved[:, 0] <= w - 1)
                & (moved[:, 1] >= 0) & (moved[:, 1] <= h - 1))
        keep &= self._moves_with_neighbours(tracks.ids, moved - tracks.centers, moved, keep)
        return _Tracks(frame, tracks.ids[keep], moved[keep], (moved - tracks.centers)[keep])

    def _neighbourhood(self, ids: np.ndarray, valid: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray]:
        """(M, K) index into ``ids`` of each marker's board neighbours (itself included,
        -1 where none is tracked), and (M, K) bool where one is."""
        board, reach = self.board, self.config.reach
        grid = np.full((board.rows + 2 * reach, board.cols + 2 * reach), -1, np.int64)
        rc = board.marker_cells(ids) + reach
        r, c = rc[:, 0], rc[:, 1]
        grid[r[valid], c[valid]] = np.flatnonzero(valid)
        index = grid[r[:, None] + self._offsets[:, 0], c[:, None] + self._offsets[:, 1]]
        return index, index >= 0

    def _coarse_shift(self, tracks: _Tracks, frame: _Frame, prior: np.ndarray
                      ) -> np.ndarray:
        """(2,) the board's motion into ``frame``: ``prior`` (its last motion) or a coarse
        estimate, whichever makes the patches match better.

        The coarse estimate is Lucas-Kanade on quarter-size copies with a deep pyramid (up
        to 32 of the centres), where the board's repeating markers have blurred into one
        blob: it does not alias onto the next marker, and it brings the fine search within
        reach of a sweep whose speed jumps from one frame to the next. Where it agrees with
        the last motion, that is kept (it is the
        finer start); where not, both are tried on those centres and the one whose fine
        search ends on the closer match is taken.
        """
        cfg = self.config
        prior = np.asarray(prior, np.float32)
        pick = np.linspace(0, len(tracks.centers) - 1, min(32, len(tracks.centers))).astype(int)
        p0 = tracks.centers[pick].reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.03)

        def search(a: np.ndarray, b: np.ndarray, points: np.ndarray, start: np.ndarray,
                   window: int, levels: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            guess = (points + start.reshape(1, 1, 2)).astype(np.float32)
            p1, status, err = cv2.calcOpticalFlowPyrLK(
                a, b, points, guess, winSize=(window, window), maxLevel=levels,
                criteria=criteria, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
            return (p1 - points).reshape(-1, 2), status.ravel() == 1, err.ravel()

        q = 0.25
        motion, good, _ = search(tracks.frame.quarter, frame.quarter,
                                 (p0 * q).astype(np.float32), prior * q,
                                 max(5, cfg.window_px // 4 | 1), max(0, cfg.coarse_levels - 2))
        if good.sum() < 3:
            return prior
        coarse = (np.median(motion[good], axis=0) / q).astype(np.float32)
        if np.linalg.norm(coarse - prior) <= cfg.window_px / 4:
            return prior
        best, best_err = prior, np.inf
        for start in (prior, coarse):
            _, ok, err = search(tracks.frame.gray, frame.gray, p0, start, cfg.window_px,
                                cfg.levels)
            score = float(np.median(err[ok])) if ok.sum() >= 3 else np.inf
            if score < best_err:
                best, best_err = start, score
        return best

    def _moves_with_neighbours(self, ids: np.ndarray, motion: np.ndarray,
                               centers: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """(M,) bool: each marker moved as its neighbours did, and they fit one homography."""
        index, have = self._neighbourhood(ids, valid)
        others = have & (index != np.arange(len(ids))[:, None])
        enough = others.sum(axis=1) >= 3
        near = np.where(others[..., None], motion[np.maximum(index, 0)], np.nan)
        median = np.zeros((len(ids), 2))
        if enough.any():
            for axis in range(2):
                median[enough, axis] = nanmedian_rows(near[enough, :, axis])
        pitch = self._pitch_px(ids, centers, index, others)
        jump = np.linalg.norm(motion - median, axis=1)
        return np.asarray(valid & enough & (jump <= self.config.max_jump * pitch))

    def _pitch_px(self, ids: np.ndarray, centers: np.ndarray, index: np.ndarray,
                  have: np.ndarray) -> np.ndarray:
        """(M,) image distance per board pitch around each marker, pixels (median)."""
        d_img = np.linalg.norm(centers[np.maximum(index, 0)] - centers[:, None], axis=2)
        d_obj = np.linalg.norm(self._object_centers[ids[np.maximum(index, 0)]]
                               - self._object_centers[ids][:, None], axis=2)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(have & (d_obj > 0), d_img / d_obj, np.nan)
        out = nanmedian_rows(ratio) if len(ids) else np.zeros(0)
        return np.where(np.isfinite(out), out, 0.0)

    def _quads(self, ids: np.ndarray, centers: np.ndarray, gray: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray]:
        """(M, 4, 2) corners from each neighbourhood's homography, and (M,) bool: fitted,
        and the marker's printed pattern is where the quad says (read in ``gray``)."""
        if len(ids) == 0:
            return np.zeros((0, 4, 2)), np.zeros(0, bool)
        index, have = self._neighbourhood(ids, np.ones(len(ids), bool))
        enough = have.sum(axis=1) >= 5
        safe = np.maximum(index, 0)
        pitch = np.maximum(self._pitch_px(ids, centers, index, have), 1e-6)
        src = self._object_centers[ids[safe]] - self._object_centers[ids][:, None]
        dst = (centers[safe] - centers[:, None]) / pitch[:, None, None]
        hom = _local_homographies(src, dst, have)
        fit = apply_h(hom, src)
        residual = np.where(have, np.linalg.norm(fit - dst, axis=2), 0.0).max(axis=1)
        corners = self._object_corners[ids] - self._object_centers[ids][:, None]
        quads = apply_h(hom, corners) * pitch[:, None, None] + centers[:, None]
        ok = enough & (residual <= self.config.max_residual) & np.isfinite(quads).all(axis=(1, 2))
        ok &= self._pattern_matches(ids, hom, pitch, centers, gray)
        return quads, ok

    def _pattern_matches(self, ids: np.ndarray, hom: np.ndarray, pitch: np.ndarray,
                         centers: np.ndarray, gray: np.ndarray) -> np.ndarray:
        """(M,) bool: the modules read at each tracked quad show the marker's pattern.

        A neighbourhood that slipped together by a whole marker keeps its shape and its
        motion agrees with itself; what it cannot keep is the pattern under each quad.
        """
        pts = apply_h(hom, self._modules[ids]) * pitch[:, None, None] + centers[:, None]
        pts = np.where(np.isfinite(pts), pts, -1.0).astype(np.float32)
        vals = cv2.remap(gray, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=0).astype(np.float64)
        white = self._white[ids]
        with np.errstate(invalid="ignore", divide="ignore"):
            mean_white = (vals * white).sum(axis=1) / white.sum(axis=1)
            mean_black = (vals * ~white).sum(axis=1) / (~white).sum(axis=1)
        threshold = 0.5 * (mean_white + mean_black)
        wrong = ((vals > threshold[:, None]) != white).sum(axis=1)
        return np.asarray((mean_white - mean_black > 8.0)
                          & (wrong <= self.config.max_wrong_modules))

    def track(self, image: np.ndarray) -> tuple[int, Detections]:
        """Follow the markers into ``image``; its frame index and the approximate markers.

        Args:
            image: (H, W) uint8/uint16 grey or (H, W, 3) uint8 BGR.

        Returns:
            (index, detections): the index to pass to :meth:`seed` with precise detections
            of this same image, and the tracked markers in full-resolution pixels (NaN
            sigmas): those whose neighbourhood gives their corners.
        """
        h, w = image.shape[:2]
        gray, scale = _small_gray(image, self.config.max_width)
        with self._lock:
            if self._size != (w, h):
                self._clear()
                self._size, self._scale = (w, h), scale
            index = self._next_index
            self._next_index += 1
            shift = np.zeros(2, np.float32)
            frame = _Frame(index, gray, _quarter(gray), shift)
            if self._tracks is not None:
                self._tracks = self._step(self._tracks, frame)
                if len(self._tracks.ids):
                    frame = replace(frame, shift=np.median(self._tracks.velocity, axis=0)
                                    .astype(np.float32))
            self._frames.append(frame)
            tracks = self._tracks
        if tracks is None:
            return index, Detections.empty((w, h), "tracked")
        quads, ok = self._quads(tracks.ids, tracks.centers.astype(np.float64), tracks.frame.gray)
        with self._lock:
            if self._tracks is tracks:  # a marker that failed a check is followed no more
                self._tracks = _Tracks(tracks.frame, tracks.ids[ok], tracks.centers[ok],
                                       tracks.velocity[ok])
        ids, centers = tracks.ids[ok], tracks.centers[ok].astype(np.float64) / scale
        order = np.argsort(ids)
        return index, Detections(ids[order], quads[ok][order] / scale, centers[order], (w, h),
                                 source="tracked")

    def seed(self, index: int, dets: Detections) -> int:
        """Take precise detections of frame ``index``; how many markers reach the newest frame.

        Its markers replace the tracked ones and are carried through the kept frames to
        the newest. A seed of a frame no longer kept, or of another image size, is
        ignored (0).
        """
        with self._lock:
            frames = [f for f in self._frames if f.index >= index]
            if not frames or frames[0].index != index or self._size != dets.image_size:
                return 0
            scale = self._scale
        centers = (dets.centers_px * scale).astype(np.float32)
        tracks = _Tracks(frames[0], dets.ids.copy(), centers, np.zeros_like(centers))
        # Carry forward outside the lock (the stream goes on meanwhile), then catch up on
        # the frames that came in since, under it.
        for frame in frames[1:]:
            tracks = self._step(tracks, frame)
        last = frames[-1].index
        with self._lock:
            if self._size != dets.image_size or not self._frames \
                    or self._frames[-1].index < last:
                return 0
            for frame in [f for f in self._frames if f.index > last]:
                tracks = self._step(tracks, frame)
            self._tracks = tracks
            return len(tracks.ids)
