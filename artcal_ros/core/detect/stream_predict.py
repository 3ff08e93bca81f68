"""A stream's candidates: the markers the frames before place, and the quad finder's elsewhere.

A :class:`~artcal_ros.core.detect.detector.Detector` fed consecutive frames knows where its
verified markers were. Their centres are followed into the new frame by pyramidal
Lucas-Kanade optical flow (on a copy at most :data:`FLOW_WIDTH` wide, started where each
centre's last velocity takes it) and each quad moved with its centre. On a repeating board a
centre can slip onto the next marker, so a quad counts only where its code reads as its own
id in its corner order. The markers that did not read are placed again by the affine map
that carries their read board neighbours' centres from the last frame to this one, and the
board's markers next to those read (entering the view, uncovered) by the homography of an
adjacent one; each again kept only where it reads as its own id. The kept quads go through
the same edge fit and verification as the quad finder's (a quad that fails is dropped, never
read as another id). The quad finder runs only on the rest of the image, the kept markers
painted over with their quiet zone's grey, so a marker the prediction missed, a second
board or a marker uncovered is still found; an id found there and also predicted elsewhere
is dropped in both places.

The whole image is searched instead (and the prediction forgotten) on the first frame, every
:data:`FULL_EVERY` frames, and whenever the prediction does not hold: fewer than
:data:`MIN_KNOWN` markers known, or fewer than :data:`MIN_HELD` of the known markers'
predictions reading as their ids (the board jumped, turned fast or left; a frame that is not
the next one), or, after verification, fewer than that share of them verified
(:meth:`StreamPredictor.fell_short`: the Detector then searches the frame again whole).
"""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.candidates import CandidateFinder
from artcal_ros.core.detect.decode import PatternTable
from artcal_ros.core.detect.sampling import bilinear, module_grid, ring_median, ring_points
from artcal_ros.core.homography import (
    apply_h,
    homographies,
    module_homographies,
    shortest_sides,
)

__all__ = ["FULL_EVERY", "MIN_HELD", "MIN_KNOWN", "StreamPredictor"]

FULL_EVERY = 10  # a whole-image search at least every this many frames
FLOW_WIDTH = 960  # frames are followed at most this wide, pixels
_FLOW_WINDOW, _FLOW_LEVELS = 21, 3  # Lucas-Kanade window (pixels there) and pyramid levels
_FLOW_POINTS = 48  # known markers followed at most; the rest are placed by them
_READ_SPREAD = 0.25  # a quad refined directly reads with samples this far apart, modules,
_PLACED_PX = 2.5  # and out to this far from its modules' edges (the edge fit's reach is ~4 px)
MIN_KNOWN = 4  # fewer verified markers in the frame before: search the whole image
MIN_HELD = 0.8  # share of the known markers' predictions that must read and verify
# a predicted quad must stay this far inside the image (pixels) to be refined directly
_INSIDE_PX = 2.0
_GROW_ROUNDS = 3  # rings of markers placed around the ones read, at most
# the eight neighbouring cells (row, col), the four sharing a side first
_NEIGHBOURS = ((0, 1), (0, -1), (1, 0), (-1, 0), (1, 1), (1, -1), (-1, 1), (-1, -1))


class StreamPredictor:
    """Predicted candidates for one stream of consecutive frames of one board.

    Args:
        board: the calibration board.
        finder: the detector's quad finder (and its pattern tables).
        min_side_px: predicted quads with a shorter side are not refined, pixels.
        quiet_modules: quiet zone around a marker's border, modules.
    """

    def __init__(self, board: Board, finder: CandidateFinder, *, min_side_px: float,
                 quiet_modules: float) -> None:
        self.board = board
        self.finder = finder
        self.min_side_px = min_side_px
        # the painted area reaches this far beyond a marker's border, modules; the quiet
        # zone's grey is read halfway across it
        self._paint_modules = min(0.75, 0.5 * quiet_modules)
        self._probe_modules = max(0.5 * quiet_modules, 0.3)
        cells = board.marker_cells(board.ids)
        self._grid = np.full((cells[:, 0].max() + 1, cells[:, 1].max() + 1), -1, np.int64)
        self._grid[cells[:, 0], cells[:, 1]] = board.ids
        self.reset()

    def reset(self) -> None:
        """Forget the frames before: the next frame is searched whole."""
        # the last frames' verified ids (N,), corners (N, 4, 2) and downscaled grey
        self._history: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._small = np.zeros((0, 0), np.uint8)  # this frame's downscaled grey
        self._size: tuple[int, int] = (0, 0)
        self._since_full = 0
        self._known: np.ndarray = np.zeros(0, np.int64)  # expected ids that read
        self.predicted = False  # this frame's candidates include predicted quads

    def find(self, gray8: np.ndarray, lin: np.ndarray, *, clipped: bool
             ) -> tuple[np.ndarray, np.ndarray]:
        """This frame's candidate quads (N, 4, 2), board corner order, and ids (N,), as
        :meth:`CandidateFinder.find` returns them.

        Args:
            gray8: (H, W) uint8 image for the quad finder.
            lin: (H, W) float32 linear intensity of the same image.
            clipped: the frame is over-exposed.
        """
        size = (gray8.shape[1], gray8.shape[0])
        self.predicted, self._known = False, np.zeros(0, np.int64)
        self._small = _downscaled(gray8)
        if (size != self._size or not self._history or self._since_full + 1 >= FULL_EVERY):
            return self._full(gray8, lin, clipped, size)
        quads, ids, known = self._predict(lin, size, clipped)
        held = np.isin(known, ids)
        if len(known) < MIN_KNOWN or held.mean() < MIN_HELD:
            return self._full(gray8, lin, clipped, size)
        # only the quads placed to a fraction of a module are refined directly (from a
        # quad further off the edge fit might settle on another edge); the quad finder
        # finds the rest
        quads, ids = self._read(lin, quads, ids, clipped, _READ_SPREAD)
        self._since_full += 1
        self.predicted, self._known = True, known[np.isin(known, ids)]
        fq, fids = self.finder.find(self._painted(gray8, quads), lin, clipped=clipped)
        return _merge(quads, ids, fq, fids)

    def fell_short(self, verified_ids: np.ndarray) -> bool:
        """Whether too few of this frame's predictions from known markers verified (the
        frame is then to be searched whole, :meth:`full_search` first)."""
        if not self.predicted or not len(self._known):
            return False
        return bool(np.isin(self._known, verified_ids).mean() < MIN_HELD)

    def full_search(self) -> None:
        """The frame about to be searched again is searched whole."""
        self.predicted, self._known, self._since_full = False, np.zeros(0, np.int64), 0

    def update(self, ids: np.ndarray, corners_px: np.ndarray) -> None:
        """Record a frame's verified markers: ids (N,), corners (N, 4, 2), pixels."""
        if len(ids) < MIN_KNOWN:
            self._history = []
            return
        self._history = [*self._history[-1:], (np.asarray(ids).copy(),
                                                np.asarray(corners_px, np.float64).copy(),
                                                self._small)]

    def _full(self, gray8: np.ndarray, lin: np.ndarray, clipped: bool, size: tuple[int, int]
              ) -> tuple[np.ndarray, np.ndarray]:
        self._size, self._since_full = size, 0
        return self.finder.find(gray8, lin, clipped=clipped)

    def _predict(self, lin: np.ndarray, size: tuple[int, int], clipped: bool
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Quads (P, 4, 2) and ids (P,) read where this frame's markers are predicted, and
        the ids of the frame before that were expected in the image.

        Up to :data:`_FLOW_POINTS` known markers (spread over the board) are followed;
        every quad placed is kept only where its code reads as its own id.
        """
        ids, corners, before = self._history[-1]
        centres = corners.mean(axis=1)
        guess = centres.copy()
        if len(self._history) == 2:
            ids0, corners0, _ = self._history[0]
            both = np.isin(ids, ids0)
            guess[both] += centres[both] - corners0[np.searchsorted(ids0, ids[both])].mean(1)
        followed = np.full_like(centres, np.nan)
        some = slice(None, None, -(-len(ids) // _FLOW_POINTS))
        followed[some] = self._flow(before, self._small, centres[some], guess[some])
        # each quad first moved as its own centre was followed: a centre that slipped
        # spoils only its own quad
        moved = corners + (followed - centres)[:, None]
        inside = self._inside(moved, size)
        # a marker whose centre was lost is still expected where its last velocity takes it
        expected = inside | (~np.isfinite(moved).all(axis=(1, 2))
                             & self._inside(corners + (guess - centres)[:, None], size))
        quads, found = self._read(lin, moved[inside], ids[inside], clipped)
        for step in range(3):
            # the markers that did not read placed again, by how the ones read moved: over
            # the whole image first (one homography, robust to the reads' few slips), then
            # each by its neighbours
            where = np.full_like(centres, np.nan)
            at = np.searchsorted(ids, found)
            ok = (at < len(ids)) & (ids[np.minimum(at, len(ids) - 1)] == found)
            where[at[ok]] = quads[ok].mean(axis=1)
            if step == 0:
                if ok.sum() < MIN_KNOWN or ok.sum() == len(ids):
                    continue
                again = _homography_moved(corners, centres, where)
            else:
                again = _moved(corners, centres, where, self.board.marker_cells(ids),
                               self._grid.shape)
            todo = self._inside(again, size) & ~np.isin(ids, found)
            q, i = self._read(lin, again[todo], ids[todo], clipped)
            if not len(i) and step:
                break
            quads, found = _unique(np.concatenate([quads, q]), np.concatenate([found, i]))
        tried = set(ids[inside].tolist()) | set(found.tolist())
        for _ in range(_GROW_ROUNDS):
            new_ids, new = self._neighbours(found, quads, tried)
            keep = self._inside(new, size)
            new_ids, new = new_ids[keep], new[keep]
            tried |= set(new_ids.tolist())
            q, i = self._read(lin, new, new_ids, clipped)
            if not len(i):
                break
            quads, found = np.concatenate([quads, q]), np.concatenate([found, i])
        return quads, found, ids[expected]

    def _inside(self, quads: np.ndarray, size: tuple[int, int]) -> np.ndarray:
        """(Q,) bool: quads (Q, 4, 2) well inside the image and large enough to refine."""
        w, h = size
        x, y = quads[..., 0], quads[..., 1]
        with np.errstate(invalid="ignore"):
            inside = ((x >= _INSIDE_PX) & (x <= w - 1 - _INSIDE_PX) & (y >= _INSIDE_PX)
                      & (y <= h - 1 - _INSIDE_PX)).all(axis=1)
            return np.asarray(inside & (shortest_sides(quads) >= self.min_side_px))

    def _flow(self, before: np.ndarray, now: np.ndarray, points: np.ndarray, guess: np.ndarray
              ) -> np.ndarray:
        """(K, 2) ``points`` (K, 2) of the frame before followed into this one (started at
        ``guess``), NaN where lost; full-resolution pixels. ``before``, ``now``: the two
        frames downscaled."""
        f = now.shape[1] / self._size[0]
        p0 = ((points + 0.5) * f - 0.5).astype(np.float32).reshape(-1, 1, 2)
        p1 = ((guess + 0.5) * f - 0.5).astype(np.float32).reshape(-1, 1, 2)
        p1, status, _ = cv2.calcOpticalFlowPyrLK(
            before, now, p0, p1, winSize=(_FLOW_WINDOW, _FLOW_WINDOW), maxLevel=_FLOW_LEVELS,
            flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 10, 0.05))
        out = (p1.reshape(-1, 2).astype(np.float64) + 0.5) / f - 0.5
        out[status.reshape(-1) == 0] = np.nan
        return out

    def _neighbours(self, ids: np.ndarray, corners: np.ndarray, tried: set[int]
                    ) -> tuple[np.ndarray, np.ndarray]:
        """The board's markers next to ``ids`` (E,) not in ``tried``, and their quads
        (E, 4, 2), each placed by the homography of an adjacent marker of ``corners``."""
        grid = self._grid
        rows, cols = grid.shape
        cells = self.board.marker_cells(ids)
        step = np.array(_NEIGHBOURS)
        # (K, 8) neighbour cells, the four sharing a side first, each placed by the first
        # marker next to it
        r = (cells[:, None, 0] + step[None, :, 0]).T.ravel()
        c = (cells[:, None, 1] + step[None, :, 1]).T.ravel()
        src = np.tile(np.arange(len(ids)), len(step))
        on = (r >= 0) & (r < rows) & (c >= 0) & (c < cols)
        j = np.full(len(r), -1, np.int64)
        j[on] = grid[r[on], c[on]]
        fresh = (j >= 0) & ~np.isin(j, np.fromiter(tried, np.int64, len(tried)))
        new_ids, first = np.unique(j[fresh], return_index=True)
        if not len(new_ids):
            return np.zeros(0, np.int64), np.zeros((0, 4, 2))
        src = src[fresh][first]
        H = homographies(self.board.object_corners(ids[src])[..., :2], corners[src])
        return new_ids, apply_h(H, self.board.object_corners(new_ids)[..., :2])

    def _read(self, lin: np.ndarray, quads: np.ndarray, ids: np.ndarray, clipped: bool,
              spread: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The quads (Q, 4, 2) whose code reads as their own id (Q,) in this corner order
        (a quad turned or slipped onto another marker does not), and those ids."""
        ok = np.zeros(len(ids), bool)
        for table in [self.finder.patterns] + ([self.finder.clipped_patterns] if clipped
                                               else []):
            ok[~ok] = _reads_as(lin, quads[~ok], ids[~ok], table, spread)
        return quads[ok], ids[ok]

    def _painted(self, gray8: np.ndarray, quads: np.ndarray) -> np.ndarray:
        """``gray8`` with each quad (Q, 4, 2) and its border's blur painted over in the grey
        of its quiet zone, so the quad finder sees plain paper there."""
        if not len(quads):
            return gray8
        n = self.board.bits + 2
        centre = quads.mean(axis=1, keepdims=True)
        grow = 1.0 + 2.0 * self._paint_modules / n
        outline = np.rint(centre + grow * (quads - centre)).astype(np.int32)
        mids = 0.5 * (quads + np.roll(quads, -1, axis=1))
        probe = centre + (1.0 + 2.0 * (self._probe_modules) / n) * (mids - centre)
        h, w = gray8.shape
        px = np.clip(np.rint(probe[..., 0]).astype(np.int64), 0, w - 1)
        py = np.clip(np.rint(probe[..., 1]).astype(np.int64), 0, h - 1)
        grey = np.median(gray8[py, px], axis=1)
        out = gray8.copy()
        for poly, g in zip(outline, grey, strict=True):
            cv2.fillConvexPoly(out, poly, int(g))
        return out


def _downscaled(gray8: np.ndarray) -> np.ndarray:
    """``gray8`` at most :data:`FLOW_WIDTH` wide (by an integer factor)."""
    k = -(-gray8.shape[1] // FLOW_WIDTH)
    if k <= 1:
        return gray8
    h, w = gray8.shape[0] // k, gray8.shape[1] // k
    return np.asarray(cv2.resize(gray8[:h * k, :w * k], (w, h), interpolation=cv2.INTER_AREA))


def _homography_moved(corners: np.ndarray, centres: np.ndarray, followed: np.ndarray
                      ) -> np.ndarray:
    """(N, 4, 2) ``corners`` moved by the one homography that carries the ``centres`` (N, 2)
    to where they were ``followed`` (N, 2, NaN where not), fitted robustly; NaN when none
    fits."""
    ok = np.isfinite(followed).all(axis=1)
    H, _ = cv2.findHomography(centres[ok], followed[ok], cv2.RANSAC, 3.0)
    if H is None:
        return np.full_like(corners, np.nan)
    return apply_h(np.broadcast_to(H, (len(corners), 3, 3)), corners)


def _moved(corners: np.ndarray, centres: np.ndarray, followed: np.ndarray, cells: np.ndarray,
           shape: tuple[int, int]) -> np.ndarray:
    """(N, 4, 2) ``corners`` moved by the affine map, per marker, that best carries its own
    and its board neighbours' ``centres`` (N, 2) to where they were ``followed`` (N, 2, NaN
    where lost); a marker lost itself is placed by at least two of its neighbours, else
    NaN. Near a marker the map is close to a
    translation: its linear part is held towards none, so a row of centres still fits.

    Args:
        cells: (N, 2) (row, col) of each marker on the board; shape: the board's cells.
    """
    n = len(centres)
    index = np.full(shape, -1, np.int64)
    index[cells[:, 0], cells[:, 1]] = np.arange(n)
    r = cells[:, 0, None] + np.array([-1, -1, -1, 0, 0, 0, 1, 1, 1])
    c = cells[:, 1, None] + np.array([-1, 0, 1, -1, 0, 1, -1, 0, 1])
    on = (r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1])
    nb = np.where(on, index[np.clip(r, 0, shape[0] - 1), np.clip(c, 0, shape[1] - 1)], -1)
    lost = ~np.isfinite(followed).all(axis=1)
    use = (nb >= 0) & ~lost[np.maximum(nb, 0)]
    src = centres[np.maximum(nb, 0)] - centres[:, None]           # (N, 9, 2)
    move = followed[np.maximum(nb, 0)] - centres[np.maximum(nb, 0)]
    w = use.astype(np.float64)
    X = np.concatenate([np.ones((n, 9, 1)), src], axis=2) * w[..., None]   # (N, 9, 3)
    A = np.einsum("nki,nkj->nij", X, X)
    scale = np.einsum("nk,nk->n", w, (src ** 2).sum(axis=2)) / np.maximum(w.sum(axis=1), 1)
    A[:, 1, 1] += 1e-3 * scale + 1e-9
    A[:, 2, 2] += 1e-3 * scale + 1e-9
    b = np.einsum("nki,nkj->nij", X, np.where(use[..., None], move, 0.0))  # (N, 3, 2)
    with np.errstate(all="ignore"):
        coef = np.linalg.solve(A + 1e-12 * np.eye(3), b)                     # (N, 3, 2)
    rel = corners - centres[:, None]
    out = corners + coef[:, None, 0] + np.einsum("nqi,nij->nqj", rel, coef[:, 1:])
    out[use.sum(axis=1) < (1 + lost)] = np.nan
    return np.asarray(out)


def _reads_as(lin: np.ndarray, quads: np.ndarray, ids: np.ndarray, table: PatternTable,
              spread: float = 0.0, max_errors: int = 2, ambiguity: float = 0.2) -> np.ndarray:
    """(Q,) bool: each quad's modules, thresholded halfway between its border's level and
    its quiet zone's, disagree with its own id's pattern (in the given corner order) in at
    most ``max_errors`` modules, and at least 60 % of them read clearly (as
    :func:`~.decode.decode_quads` reads a quad). A module is read at its centre, or with
    ``spread`` > 0 at 3 x 3 samples at least that far apart (modules), all of which must
    agree, and on large modules out to :data:`_PLACED_PX` of their edges: a quad placed a
    quarter module or that many pixels off does not read so."""
    if not len(ids):
        return np.zeros(0, bool)
    n = table.n
    H = module_homographies(np.ascontiguousarray(quads, dtype=np.float64), n - 2)
    if spread == 0:
        grid = module_grid(n, 0.0)[4::9]
        pts = apply_h(H, np.broadcast_to(grid, (len(H), *grid.shape)))
    else:
        # at least spread, and on large modules out to _PLACED_PX of the module's edges
        module_px = shortest_sides(quads) / n
        s = np.clip(0.5 - _PLACED_PX / np.maximum(module_px, 1e-9), spread, 0.45)
        unit = module_grid(n, 1.0) - module_grid(n, 0.0)
        grid = module_grid(n, 0.0)[None] + s[:, None, None] * unit[None]
        pts = apply_h(H, grid)
    vals = bilinear(lin, pts[..., 0], pts[..., 1]).reshape(len(ids), n * n, -1)
    quiet = ring_median(lin, H, ring_points(np.linspace(0.5, n - 0.5, 2 * n), -0.5, n + 0.5))
    edge = np.ones((n, n), bool)
    edge[1:-1, 1:-1] = False
    level = np.median(vals[:, edge.ravel()].mean(axis=2), axis=1)
    thr = 0.5 * (level + quiet)
    band = ambiguity * np.abs(quiet - level)
    white = (vals > (thr + band)[:, None, None]).all(axis=2)
    black = (vals < (thr - band)[:, None, None]).all(axis=2)
    # the table lists the board's ids in order (then their inverses, any polarity)
    best = np.full(len(ids), n * n)
    for first in range(0, len(table.ids), len(np.unique(table.ids))):
        pat = table.flat[first + ids - table.ids[first]] > 0.5
        best = np.minimum(best, (white & ~pat).sum(axis=1) + (black & pat).sum(axis=1))
    sure = (white | black).mean(axis=1)
    return np.asarray((best <= max_errors) & (sure >= 0.6))


def _same_place(quad: np.ndarray, other: np.ndarray) -> bool:
    """Two reads of one id are one marker: ``other``'s centre within half of ``quad``'s
    shortest side of ``quad``'s (both (4, 2) pixels)."""
    d = np.linalg.norm(other.mean(axis=0) - quad.mean(axis=0))
    return bool(d <= 0.5 * shortest_sides(quad[None])[0])


def _unique(quads: np.ndarray, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Candidates with each id once: where an id is read at one place (quads within half a
    side of each other) the first is kept, at two places all are dropped."""
    order = np.argsort(ids, kind="stable")
    quads, ids = quads[order], ids[order]
    keep = np.ones(len(ids), bool)
    for i in np.flatnonzero(np.diff(ids) == 0):
        if not keep[i + 1]:
            continue
        if not _same_place(quads[i], quads[i + 1]):
            keep[ids == ids[i]] = False
        else:
            keep[i + 1] = False
    return quads[keep], ids[keep]


def _merge(quads: np.ndarray, ids: np.ndarray, found_quads: np.ndarray, found_ids: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """Predicted and found candidates together. A found id that was predicted is the same
    marker when it lies on the predicted quad (the predicted one is kept); elsewhere one of
    the two is wrong and which cannot be told here: both are dropped."""
    pos = {int(i): k for k, i in enumerate(ids)}
    keep_found = np.ones(len(found_ids), bool)
    keep_pred = np.ones(len(ids), bool)
    for k, i in enumerate(found_ids):
        j = pos.get(int(i))
        if j is None:
            continue
        keep_found[k] = False
        if not _same_place(quads[j], found_quads[k]):
            keep_pred[j] = False
    return (np.concatenate([quads[keep_pred], found_quads[keep_found]]),
            np.concatenate([ids[keep_pred], found_ids[keep_found]]))
