"""The squares of a chessboard or a ChArUco board, their inner corners and marker squares.

Both are ``squares_x`` x ``squares_y`` squares of side ``square_length`` (metres) whose
outer top-left corner sits at ``origin_m`` in the board frame (x right, y down, z = 0).

- Inner corners (the saddle points) are numbered row-major over the
  ``(squares_x - 1) x (squares_y - 1)`` grid; corner ``k`` in row ``r = k // (squares_x - 1)``,
  column ``c = k % (squares_x - 1)`` sits at ``origin_m + ((c + 1) s, (r + 1) s)``. For a
  ChArUco board this is OpenCV's charuco corner id (``getChessboardCorners``); for a
  chessboard it is ``findChessboardCorners``' order with the origin at corner 0.
- Square (row ``i``, column ``j``) is black when ``(i + j) % 2 == 0``: the top-left square is
  black, as OpenCV draws both boards. OpenCV's legacy ChArUco pattern (before 4.6) starts
  with a white square on boards with an even number of rows: ``white_top_left``.
- A ChArUco board puts one marker, centred, in every white square, row-major (OpenCV's
  marker ids 0, 1, ... in that order).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np


@dataclass(frozen=True)
class ChessLayout:
    """The square pattern of a chessboard or ChArUco board (lengths in metres)."""

    squares_x: int
    squares_y: int
    square_length: float
    origin_m: tuple[float, float] = (0.0, 0.0)
    white_top_left: bool = False

    @property
    def corner_cols(self) -> int:
        """Inner corners per row."""
        return self.squares_x - 1

    @property
    def corner_rows(self) -> int:
        """Inner corners per column."""
        return self.squares_y - 1

    @property
    def n_corners(self) -> int:
        """Number of inner corners."""
        return self.corner_cols * self.corner_rows

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) of the squares' outer edges, board frame, metres."""
        x0, y0 = self.origin_m
        s = self.square_length
        return x0, y0, x0 + self.squares_x * s, y0 + self.squares_y * s

    def square_is_black(self, row: np.ndarray, col: np.ndarray) -> np.ndarray:
        """Whether square (row, col) is black (vectorised)."""
        parity = (np.asarray(row) + np.asarray(col)) % 2
        return np.asarray(parity == (1 if self.white_top_left else 0))

    def corner_cells(self, ids: np.ndarray) -> np.ndarray:
        """(M, 2) int64 (row, col) of inner corners in the corner grid."""
        k = np.asarray(ids, dtype=np.int64).reshape(-1)
        return np.stack([k // self.corner_cols, k % self.corner_cols], axis=1)

    def corner_points(self, ids: np.ndarray) -> np.ndarray:
        """(M, 3) float64 board-frame positions of inner corners, metres."""
        rc = self.corner_cells(ids)
        out = np.zeros((len(rc), 3))
        out[:, 0] = self.origin_m[0] + (rc[:, 1] + 1) * self.square_length
        out[:, 1] = self.origin_m[1] + (rc[:, 0] + 1) * self.square_length
        return out

    def corner_black_diagonal(self, ids: np.ndarray) -> np.ndarray:
        """(M,) bool: the squares up-left and down-right of each inner corner are black."""
        rc = self.corner_cells(ids)
        return self.square_is_black(rc[:, 0], rc[:, 1])

    @cached_property
    def white_squares(self) -> np.ndarray:
        """(K, 2) int64 (row, col) of the white squares, row-major (ChArUco marker order)."""
        r, c = np.mgrid[0:self.squares_y, 0:self.squares_x]
        white = ~self.square_is_black(r, c)
        return np.stack([r[white], c[white]], axis=1).astype(np.int64)

    @cached_property
    def marker_at_square(self) -> np.ndarray:
        """(squares_y, squares_x) int64: marker index in each white square, -1 on black."""
        table = np.full((self.squares_y, self.squares_x), -1, np.int64)
        ws = self.white_squares
        table[ws[:, 0], ws[:, 1]] = np.arange(len(ws))
        return table

    def square_of(self, x_m: np.ndarray, y_m: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                     np.ndarray]:
        """(row, col, inside) of the square holding each board point (vectorised)."""
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        col = np.floor((x - self.origin_m[0]) / self.square_length).astype(np.int64)
        row = np.floor((y - self.origin_m[1]) / self.square_length).astype(np.int64)
        inside = (col >= 0) & (col < self.squares_x) & (row >= 0) & (row < self.squares_y)
        return row, col, inside

    def squares_white(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Whether board points are white on the squares alone (paper white outside them)."""
        row, col, inside = self.square_of(x_m, y_m)
        return ~(inside & self.square_is_black(row, col))

    def lines_m(self) -> tuple[np.ndarray, np.ndarray]:
        """Board x and y positions of every square edge, metres."""
        s = self.square_length
        return (self.origin_m[0] + np.arange(self.squares_x + 1) * s,
                self.origin_m[1] + np.arange(self.squares_y + 1) * s)
