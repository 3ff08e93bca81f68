"""The marker-grid calibration board: geometry, ids, polarity and object points.

Geometry and conventions follow OpenCV's ``cv2.aruco.GridBoard``: marker
``first_id`` sits top-left, ids run row-major, the board frame's origin is the
top-left outer corner of that marker, x right, y down, z = 0 on the board,
units metres. Each marker's four corners are listed top-left, top-right,
bottom-right, bottom-left on the board; its centre is the square's centre.

A marker is ``bits + 2`` modules wide (a one-module border around the code).
With polarity ``black`` a marker is a black border on white paper; ``white``
is the reverse (a white border on black); ``mixed`` alternates the two like a
chequerboard, each marker sitting on a tile of the opposite colour.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.errors import BoardError

POLARITIES = ("black", "white", "mixed", "any")


def dictionary_by_name(name: str) -> cv2.aruco.Dictionary:
    """The OpenCV predefined ArUco dictionary called ``name`` (e.g. ``DICT_6X6_1000``)."""
    code = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    if not isinstance(code, int):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
        raise BoardError(f"parameter 'board.dictionary': unknown dictionary {name!r}; "
                         f"use one of {', '.join(known)}")
    return cv2.aruco.getPredefinedDictionary(code)


@dataclass(frozen=True)
class Board:
    """A grid of ``cols`` x ``rows`` square markers (lengths in metres).

    Build one with :meth:`from_params` or directly; invalid values raise
    :class:`BoardError` naming the parameter.
    """

    cols: int = 19
    rows: int = 9
    marker_length: float = 0.06
    marker_separation: float = 0.02
    first_id: int = 0
    dictionary_name: str = "DICT_6X6_1000"
    polarity: str = "black"
    _dictionary: Any = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.cols < 1:
            raise BoardError(f"parameter 'board.cols': {self.cols} must be >= 1")
        if self.rows < 1:
            raise BoardError(f"parameter 'board.rows': {self.rows} must be >= 1")
        if not self.marker_length > 0:
            raise BoardError(f"parameter 'board.marker_length': {self.marker_length} "
                             "must be > 0 (metres)")
        if not self.marker_separation > 0:
            raise BoardError(f"parameter 'board.marker_separation': {self.marker_separation} "
                             "must be > 0 (metres)")
        if self.first_id < 0:
            raise BoardError(f"parameter 'board.first_id': {self.first_id} must be >= 0")
        if self.polarity not in POLARITIES:
            raise BoardError(f"parameter 'board.polarity': {self.polarity!r} is not one of "
                             f"{', '.join(POLARITIES)}")
        dictionary = dictionary_by_name(self.dictionary_name)
        object.__setattr__(self, "_dictionary", dictionary)
        size = int(dictionary.bytesList.shape[0])
        last = self.first_id + self.cols * self.rows - 1
        if last >= size:
            raise BoardError(
                f"parameter 'board.first_id'/'board.cols'/'board.rows': the board needs ids "
                f"{self.first_id}..{last} but {self.dictionary_name} has only ids 0..{size - 1}; "
                "use fewer markers, a lower first_id or a larger dictionary")
        # A marker needs a quiet zone of at least one module of the opposite colour
        # around its border; with mixed polarity each marker only owns half the gap.
        need = self.module_length * (2.0 if self.polarity == "mixed" else 1.0)
        if self.marker_separation < need - 1e-12:
            raise BoardError(
                f"parameter 'board.marker_separation': {self.marker_separation} m is too small "
                f"for the quiet zone around each marker; use at least {need:.4g} m "
                f"({'two modules' if self.polarity == 'mixed' else 'one module'} of "
                f"{self.module_length:.4g} m)")

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Board:
        """A board from the flat ``board.*`` parameters (see :func:`load_params`)."""
        board_type = params.get("board.type", "marker_grid")
        if board_type != "marker_grid":
            raise BoardError(f"parameter 'board.type': {board_type!r} is not supported; "
                             "use marker_grid")
        return cls(
            cols=int(params.get("board.cols", 19)),
            rows=int(params.get("board.rows", 9)),
            marker_length=float(params.get("board.marker_length", 0.06)),
            marker_separation=float(params.get("board.marker_separation", 0.02)),
            first_id=int(params.get("board.first_id", 0)),
            dictionary_name=str(params.get("board.dictionary", "DICT_6X6_1000")),
            polarity=str(params.get("board.polarity", "black")),
        )

    # --- geometry -----------------------------------------------------------------
    @property
    def dictionary(self) -> cv2.aruco.Dictionary:
        """The OpenCV dictionary of the markers."""
        return self._dictionary

    @property
    def bits(self) -> int:
        """Code cells per marker side (6 for 6x6 dictionaries)."""
        return int(self._dictionary.markerSize)

    @property
    def module_length(self) -> float:
        """Side of one code cell (module), metres: marker_length / (bits + 2)."""
        return self.marker_length / (self.bits + 2)

    @property
    def pitch(self) -> float:
        """Distance between neighbouring markers' origins, metres."""
        return self.marker_length + self.marker_separation

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the marker area, outer edge to outer edge, metres."""
        return (self.cols * self.pitch - self.marker_separation,
                self.rows * self.pitch - self.marker_separation)

    @property
    def margin_m(self) -> float:
        """Quiet margin printed around the marker area, metres."""
        return max(self.marker_separation, 2.0 * self.module_length)

    @cached_property
    def ids(self) -> np.ndarray:
        """(N,) int: every marker id, row-major."""
        return np.arange(self.first_id, self.first_id + self.cols * self.rows, dtype=np.int64)

    def has_id(self, marker_id: int) -> bool:
        """Whether ``marker_id`` belongs to this board."""
        return self.first_id <= marker_id < self.first_id + self.cols * self.rows

    def cell_of(self, marker_id: int) -> tuple[int, int]:
        """(row, col) of a marker on the board; BoardError for an id not on it."""
        if not self.has_id(marker_id):
            raise BoardError(f"marker id {marker_id} is not on this board "
                             f"(ids {self.first_id}..{self.ids[-1]})")
        k = marker_id - self.first_id
        return k // self.cols, k % self.cols

    def has_ids(self, marker_ids: np.ndarray) -> np.ndarray:
        """(N,) bool: which of ``marker_ids`` (N,) belong to this board."""
        k = np.asarray(marker_ids, dtype=np.int64).reshape(-1) - self.first_id
        return (k >= 0) & (k < self.cols * self.rows)

    def cells_of(self, marker_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows (N,), cols (N,)) int64 of markers on the board; BoardError for ids not on it."""
        k = np.asarray(marker_ids, dtype=np.int64) - self.first_id
        if k.size and (k.min() < 0 or k.max() >= self.cols * self.rows):
            bad = np.asarray(marker_ids)[(k < 0) | (k >= self.cols * self.rows)]
            raise BoardError(f"marker ids {bad.tolist()} are not on this board")
        return k // self.cols, k % self.cols

    def object_corners(self, marker_ids: np.ndarray | None = None) -> np.ndarray:
        """(N, 4, 3) float64, metres: each marker's corners TL, TR, BR, BL in the board frame."""
        ids = self.ids if marker_ids is None else np.asarray(marker_ids)
        rows, cols = self.cells_of(ids)
        x0 = cols * self.pitch
        y0 = rows * self.pitch
        L = self.marker_length
        out = np.zeros((len(ids), 4, 3))
        out[:, :, 0] = x0[:, None] + np.array([0.0, L, L, 0.0])
        out[:, :, 1] = y0[:, None] + np.array([0.0, 0.0, L, L])
        return out

    def object_centers(self, marker_ids: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) float64, metres: each marker's centre in the board frame."""
        return self.object_corners(marker_ids).mean(axis=1)

    # --- appearance ---------------------------------------------------------------
    def is_inverted(self, marker_id: int) -> bool:
        """True where the marker is printed white-on-black (see the module docstring)."""
        if self.polarity == "white":
            return True
        if self.polarity == "mixed":
            row, col = self.cell_of(marker_id)
            return (row + col) % 2 == 1
        return False

    @cached_property
    def _marker_modules(self) -> np.ndarray:
        """(N, bits+2, bits+2) bool: True where each marker (as printed) is white."""
        n = self.bits + 2
        out = np.zeros((len(self.ids), n, n), dtype=bool)
        for k, marker_id in enumerate(self.ids):
            img = cv2.aruco.generateImageMarker(self._dictionary, int(marker_id), n, borderBits=1)
            white = img > 127
            out[k] = ~white if self.is_inverted(int(marker_id)) else white
        return out

    def marker_modules(self, marker_id: int) -> np.ndarray:
        """(bits+2, bits+2) bool: the printed marker, True = white, row 0 at the top."""
        row, col = self.cell_of(marker_id)
        return self._marker_modules[row * self.cols + col]

    def is_white(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Whether board points are printed white (vectorised, exact edges).

        Args:
            x_m, y_m: same-shape arrays of board-frame coordinates, metres.

        Returns:
            bool array of that shape. Points beyond the printed margin read as the
            background of the nearest tile.
        """
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        half = 0.5 * self.marker_separation
        col = np.floor((x + half) / self.pitch).astype(np.int64)
        row = np.floor((y + half) / self.pitch).astype(np.int64)
        col_c = np.clip(col, 0, self.cols - 1)
        row_c = np.clip(row, 0, self.rows - 1)
        u = x - col_c * self.pitch
        v = y - row_c * self.pitch
        k = row_c * self.cols + col_c
        inverted = np.array([self.is_inverted(int(i)) for i in self.ids], dtype=bool)
        out = ~inverted[k]  # tile background: white around a black marker
        inside = (u >= 0) & (u < self.marker_length) & (v >= 0) & (v < self.marker_length)
        n = self.bits + 2
        mc = np.clip((u[inside] / self.module_length).astype(np.int64), 0, n - 1)
        mr = np.clip((v[inside] / self.module_length).astype(np.int64), 0, n - 1)
        out[inside] = self._marker_modules[k[inside], mr, mc]
        return out

    def to_cv_board(self) -> cv2.aruco.GridBoard:
        """The equivalent ``cv2.aruco.GridBoard`` (same ids and object points)."""
        return cv2.aruco.GridBoard((self.cols, self.rows), self.marker_length,
                                   self.marker_separation, self._dictionary,
                                   self.ids.astype(np.int32))

    def describe(self) -> str:
        """One line stating the board's parameters (printed on the board's margin)."""
        w, h = self.size_m
        return (f"artcal marker_grid {self.cols}x{self.rows} {self.dictionary_name} "
                f"ids {self.first_id}..{int(self.ids[-1])} "
                f"marker {self.marker_length * 1000:g} mm "
                f"gap {self.marker_separation * 1000:g} mm polarity {self.polarity} "
                f"({w * 1000:g} x {h * 1000:g} mm)")
