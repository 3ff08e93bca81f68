"""Circle grids: OpenCV's symmetric (``circles``) and asymmetric (``acircles``) patterns.

``cols`` x ``rows`` is ``findCirclesGrid``'s ``patternSize``: ``cols`` circles per row,
``rows`` rows. ``spacing`` (``board.square_length``, metres) is OpenCV's ``squareSize``:

- symmetric (``CALIB_CB_SYMMETRIC_GRID``): circle ``k`` in row ``i = k // cols``, column
  ``j = k % cols`` sits at ``(j * spacing, i * spacing)``;
- asymmetric (``CALIB_CB_ASYMMETRIC_GRID``): at ``((2 j + i % 2) * spacing, i * spacing)``,
  as OpenCV's calibration sample lays its object points out: odd rows shifted by one spacing,
  neighbours in a row two spacings apart.

The board frame's origin is the centre of circle 0, x right, y down, z = 0 (metres). Every
circle is black on white paper, of diameter ``DIAMETER_PER_SPACING * spacing``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# OpenCV's pattern generator (doc/pattern_tools/gen_pattern.py) draws circles of radius
# spacing / 5 by default: the same diameter here, so its prints and these agree.
DIAMETER_PER_SPACING = 0.4


@dataclass(frozen=True)
class CircleLayout:
    """The circles of a ``circles`` or ``acircles`` board (lengths in metres)."""

    cols: int
    rows: int
    spacing: float
    asymmetric: bool

    @property
    def n_circles(self) -> int:
        """Number of circles (point ids 0 .. n - 1)."""
        return self.cols * self.rows

    @property
    def radius(self) -> float:
        """Radius of every circle, metres."""
        return 0.5 * DIAMETER_PER_SPACING * self.spacing

    def cells(self, ids: np.ndarray) -> np.ndarray:
        """(M, 2) int64 (row, column) of circles on the lattice of spacing ``spacing``:
        (i, j) of findCirclesGrid's order on a symmetric grid, (i, 2 j + i % 2) on an
        asymmetric one (so that positions are linear in the cells on both)."""
        k = np.asarray(ids, dtype=np.int64).reshape(-1)
        i, j = k // self.cols, k % self.cols
        return np.stack([i, 2 * j + i % 2 if self.asymmetric else j], axis=1)

    def centres(self, ids: np.ndarray) -> np.ndarray:
        """(M, 3) float64 board-frame centres of circles, metres (z = 0)."""
        rc = self.cells(ids)
        out = np.zeros((len(rc), 3))
        out[:, 0] = rc[:, 1] * self.spacing
        out[:, 1] = rc[:, 0] * self.spacing
        return out

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) of the circles' outer edges, board frame, metres."""
        r = self.radius
        width = (2 * (self.cols - 1) + (1 if self.rows > 1 else 0)) if self.asymmetric \
            else self.cols - 1
        return -r, -r, width * self.spacing + r, (self.rows - 1) * self.spacing + r

    def nearest(self, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(distance to the nearest circle's centre, metres; its id) of board points."""
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        s = self.spacing
        best = np.full(x.shape, np.inf)
        best_id = np.zeros(x.shape, np.int64)
        base = np.floor(y / s).astype(np.int64)
        # the nearest circle is in the row just above or just below the point
        for row in (np.clip(base, 0, self.rows - 1), np.clip(base + 1, 0, self.rows - 1)):
            shift = (row % 2) if self.asymmetric else 0
            step = 2 if self.asymmetric else 1
            col = np.clip(np.rint((x / s - shift) / step), 0, self.cols - 1).astype(np.int64)
            d = np.hypot(x - (step * col + shift) * s, y - row * s)
            closer = d < best
            best = np.where(closer, d, best)
            best_id = np.where(closer, row * self.cols + col, best_id)
        return best, best_id

    def is_white(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Whether board points are printed white (outside every circle)."""
        d, _ = self.nearest(x_m, y_m)
        return np.asarray(d >= self.radius)
