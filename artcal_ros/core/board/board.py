"""The calibration board: geometry, ids, polarity and object points of every board type.

``board.type`` selects the layout (see docs/conventions.md for each home tool's names):

- ``marker_grid`` follows OpenCV's ``cv2.aruco.GridBoard``: marker ``first_id`` sits
  top-left, ids run row-major, the board frame's origin is the top-left outer corner of
  that marker, x right, y down, z = 0 on the board, units metres. Each marker's four
  corners are listed top-left, top-right, bottom-right, bottom-left on the board; its
  centre is the square's centre.
- ``chessboard`` is camera_calibration's: ``cols`` x ``rows`` inner corners (``--size``),
  squares of ``square_length``; point ids in ``findChessboardCorners`` order (row-major),
  the origin at corner 0.
- ``charuco`` is OpenCV's ``CharucoBoard``: ``cols`` x ``rows`` squares (squaresX,
  squaresY), a marker in every white square, point ids OpenCV's charuco corner ids, the
  origin at the squares' top-left outer corner, ``legacy_pattern`` as ``setLegacyPattern``.
- ``aprilgrid`` is Kalibr's AprilGrid (:mod:`artcal_ros.core.board.aprilgrid`) in the
  marker grid's frame: Kalibr's tag ids (tag 0 bottom-left) and point ids (the tag corners).
- ``circles`` and ``acircles`` are OpenCV's symmetric and asymmetric circle grids
  (:mod:`artcal_ros.core.board.circles`): ``cols`` x ``rows`` is findCirclesGrid's
  patternSize, ``square_length`` the circle spacing, point ids findCirclesGrid's order.

A marker is ``bits + 2`` modules wide (a one-module border around the code).
With polarity ``black`` a marker is a black border on white paper; ``white``
is the reverse (a white border on black); ``mixed`` alternates the two like a
chequerboard, each marker sitting on a tile of the opposite colour. ChArUco markers are
black on their white squares.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board import aprilgrid as kalibr
from artcal_ros.core.board.chess import ChessLayout
from artcal_ros.core.board.circles import CircleLayout
from artcal_ros.core.board.dictionaries import predefined_code, predefined_names
from artcal_ros.core.board.text import cv_board, describe, print_lines, size_parameters
from artcal_ros.core.board.types import BUILT_TYPES, PLANNED_TYPES, POINT_TYPES
from artcal_ros.core.errors import BoardError

POLARITIES = ("black", "white", "mixed", "any")


def dictionary_by_name(name: str) -> cv2.aruco.Dictionary:
    """The OpenCV predefined ArUco dictionary called ``name`` (e.g. ``DICT_6X6_1000``)."""
    code = predefined_code(name)
    if code is None:
        raise BoardError(f"parameter 'board.dictionary': unknown dictionary {name!r}; "
                         f"use one of {', '.join(predefined_names())}")
    return cv2.aruco.getPredefinedDictionary(code)


def board_type_complaint(board_type: str) -> str | None:
    """Why ``board_type`` cannot be used (None when it is built)."""
    if board_type in BUILT_TYPES:
        return None
    if board_type in PLANNED_TYPES:
        return (f"{board_type!r} is not built yet; the built types are "
                f"{', '.join(BUILT_TYPES)}")
    return f"{board_type!r} is not a board type; use one of {', '.join(BUILT_TYPES)}"


@dataclass(frozen=True)
class Board:
    """A calibration board (lengths in metres); ``board_type`` says which layout.

    ``cols`` x ``rows`` counts markers (marker_grid), inner corners (chessboard), squares
    (charuco) or circles (circles, acircles). Build one with :meth:`from_params` or
    directly; invalid values raise :class:`BoardError` naming the parameter.
    """

    cols: int = 19
    rows: int = 9
    marker_length: float = 0.06
    marker_separation: float = 0.02
    first_id: int = 0
    dictionary_name: str = "DICT_6X6_1000"
    polarity: str = "black"
    board_type: str = "marker_grid"
    square_length: float = 0.08
    legacy_pattern: bool = False
    _dictionary: Any = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        complaint = board_type_complaint(self.board_type)
        if complaint:
            raise BoardError(f"parameter 'board.type': {complaint}")
        least = 1 if self.board_type in ("marker_grid", "aprilgrid") else 2
        if self.cols < least:
            raise BoardError(f"parameter 'board.cols': {self.cols} must be >= {least}")
        if self.rows < least:
            raise BoardError(f"parameter 'board.rows': {self.rows} must be >= {least}")
        if self.first_id < 0:
            raise BoardError(f"parameter 'board.first_id': {self.first_id} must be >= 0")
        if self.polarity not in POLARITIES:
            raise BoardError(f"parameter 'board.polarity': {self.polarity!r} is not one of "
                             f"{', '.join(POLARITIES)}")
        if self.board_type != "marker_grid" and not self.square_length > 0:
            raise BoardError(f"parameter 'board.square_length': {self.square_length} "
                             "must be > 0 (metres)")
        if self.board_type in ("chessboard", "circles", "acircles"):
            return
        if not self.marker_length > 0:
            raise BoardError(f"parameter 'board.marker_length': {self.marker_length} "
                             "must be > 0 (metres)")
        if self.board_type == "aprilgrid":
            dictionary = self._aprilgrid_dictionary()
        else:
            dictionary = dictionary_by_name(self.dictionary_name)
        object.__setattr__(self, "_dictionary", dictionary)
        size = int(dictionary.bytesList.shape[0])
        last = self.first_id + self.n_markers - 1
        if last >= size:
            raise BoardError(
                f"parameter 'board.first_id'/'board.cols'/'board.rows': the board needs ids "
                f"{self.first_id}..{last} but {self.dictionary_name} has only ids 0..{size - 1}; "
                "use fewer markers, a lower first_id or a larger dictionary")
        if self.board_type == "charuco":
            self._check_charuco()
            return
        if not self.marker_separation > 0:
            raise BoardError(f"parameter 'board.marker_separation': {self.marker_separation} "
                             "must be > 0 (metres)")
        # A marker needs a quiet zone of at least one module of the opposite colour
        # around its border; with mixed polarity each marker only owns half the gap.
        need = self.module_length * (2.0 if self.polarity == "mixed" else 1.0)
        if self.marker_separation < need - 1e-12:
            raise BoardError(
                f"parameter 'board.marker_separation': {self.marker_separation} m is too small "
                f"for the quiet zone around each marker; use at least {need:.4g} m "
                f"({'two modules' if self.polarity == 'mixed' else 'one module'} of "
                f"{self.module_length:.4g} m)")

    def _aprilgrid_dictionary(self) -> cv2.aruco.Dictionary:
        complaint = kalibr.aprilgrid_complaint(self.dictionary_name, self.polarity,
                                               self.first_id)
        if complaint:
            raise BoardError(complaint)
        object.__setattr__(self, "dictionary_name", "tag36h11")
        return kalibr.aprilgrid_dictionary(self.cols * self.rows)

    def _check_charuco(self) -> None:
        if not self.marker_length < self.square_length:
            raise BoardError(
                f"parameter 'board.marker_length': {self.marker_length} m must be smaller "
                f"than board.square_length ({self.square_length} m) on a charuco board")
        if self.polarity != "black":
            raise BoardError(f"parameter 'board.polarity': {self.polarity!r}; a charuco board "
                             "prints black markers on its white squares: use black")

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> Board:
        """A board from the flat ``board.*`` parameters (see :func:`load_params`)."""
        return cls(
            cols=int(params.get("board.cols", 19)),
            rows=int(params.get("board.rows", 9)),
            marker_length=float(params.get("board.marker_length", 0.06)),
            marker_separation=float(params.get("board.marker_separation", 0.02)),
            first_id=int(params.get("board.first_id", 0)),
            dictionary_name=str(params.get("board.dictionary", "DICT_6X6_1000")),
            polarity=str(params.get("board.polarity", "black")),
            board_type=str(params.get("board.type", "marker_grid")),
            square_length=float(params.get("board.square_length", 0.08)),
            legacy_pattern=bool(params.get("board.legacy_pattern", False)),
        )

    def to_params(self) -> dict[str, Any]:
        """The ``board.*`` parameters that rebuild this board with :meth:`from_params`."""
        return {"board.type": self.board_type, "board.dictionary": self.dictionary_name,
                "board.cols": self.cols, "board.rows": self.rows,
                "board.marker_length": self.marker_length,
                "board.marker_separation": self.marker_separation,
                "board.first_id": self.first_id, "board.polarity": self.polarity,
                "board.square_length": self.square_length,
                "board.legacy_pattern": self.legacy_pattern}

    @property
    def size_parameters(self) -> str:
        """The parameters that set the board's geometry, for messages."""
        return size_parameters(self)

    # --- layout -------------------------------------------------------------------
    @cached_property
    def chess(self) -> ChessLayout | None:
        """The square pattern of a chessboard or ChArUco board (None for a marker grid)."""
        s = self.square_length
        if self.board_type == "chessboard":
            return ChessLayout(self.cols + 1, self.rows + 1, s, (-s, -s))
        if self.board_type == "charuco":
            return ChessLayout(self.cols, self.rows, s, (0.0, 0.0),
                               white_top_left=self.legacy_pattern and self.rows % 2 == 0)
        return None

    @cached_property
    def circles(self) -> CircleLayout | None:
        """The circles of a ``circles`` or ``acircles`` board (None on other boards)."""
        if self.board_type not in ("circles", "acircles"):
            return None
        return CircleLayout(self.cols, self.rows, self.square_length,
                            self.board_type == "acircles")

    @property
    def has_points(self) -> bool:
        """Whether the board's correspondences are its points (saddle points), not markers."""
        return self.board_type in POINT_TYPES

    @property
    def n_markers(self) -> int:
        """Number of markers on the board (0 for a chessboard or a circle grid)."""
        if self.circles is not None:
            return 0
        if self.chess is not None:
            return 0 if self.board_type == "chessboard" else len(self.chess.white_squares)
        return self.cols * self.rows

    @cached_property
    def point_ids(self) -> np.ndarray:
        """(M,) int64: every point id (inner corners; empty for a marker grid)."""
        if self.board_type == "aprilgrid":
            return np.arange(4 * self.n_markers, dtype=np.int64)
        if self.circles is not None:
            return np.arange(self.circles.n_circles, dtype=np.int64)
        return np.arange(0 if self.chess is None else self.chess.n_corners, dtype=np.int64)

    def _check_point_ids(self, ids: np.ndarray) -> np.ndarray:
        k = np.asarray(ids, dtype=np.int64).reshape(-1)
        n = len(self.point_ids)
        if k.size and (k.min() < 0 or k.max() >= n):
            raise BoardError(f"point ids {k[(k < 0) | (k >= n)].tolist()} are not on this "
                             f"board (ids 0..{n - 1})")
        return k

    def object_points(self, point_ids: np.ndarray | None = None) -> np.ndarray:
        """(M, 3) float64, metres: the board-frame position of each point id."""
        ids = self.point_ids if point_ids is None else self._check_point_ids(point_ids)
        if self.board_type == "aprilgrid":
            return kalibr.kalibr_points(ids, self.cols, self.rows, self.marker_length,
                                        self.marker_separation)
        if self.circles is not None:
            return self.circles.centres(ids)
        if self.chess is None:
            return np.zeros((0, 3))
        return self.chess.corner_points(ids)

    def marker_point_ids(self, marker_ids: np.ndarray) -> np.ndarray:
        """(N, 4) int64: the point id of each marker's corners TL, TR, BR, BL (aprilgrid:
        Kalibr's point ids); BoardError on other boards."""
        if self.board_type != "aprilgrid":
            raise BoardError(f"a {self.board_type} has no point ids on its markers")
        self._cells(marker_ids)
        return kalibr.kalibr_corner_ids(marker_ids, self.cols)

    def point_cells(self, point_ids: np.ndarray) -> np.ndarray:
        """(M, 2) int64 (row, col) of each point in the board's grid of points."""
        ids = self._check_point_ids(point_ids)
        if self.board_type == "aprilgrid":
            return kalibr.point_cells(ids, self.cols, self.rows)
        if self.circles is not None:
            return self.circles.cells(ids)
        if self.chess is None:
            return np.zeros((0, 2), np.int64)
        return self.chess.corner_cells(ids)

    @property
    def dictionary(self) -> cv2.aruco.Dictionary:
        """The OpenCV dictionary of the markers (None on a chessboard)."""
        return self._dictionary

    @property
    def bits(self) -> int:
        """Code cells per marker side (6 for 6x6 dictionaries; 0 without markers)."""
        return 0 if self._dictionary is None else int(self._dictionary.markerSize)

    @property
    def module_length(self) -> float:
        """Side of one code cell (module), metres: marker_length / (bits + 2)."""
        return self.marker_length / (self.bits + 2)

    @property
    def pitch(self) -> float:
        """Distance between neighbouring markers' origins (squares on a chess pattern), m."""
        if self.chess is not None:
            return self.square_length
        return self.marker_length + self.marker_separation

    @property
    def quiet_zone_m(self) -> float:
        """White (or black) paper a marker owns around its border, metres."""
        if self.board_type == "charuco":
            return 0.5 * (self.square_length - self.marker_length)
        return self.marker_separation * (0.5 if self.polarity == "mixed" else 1.0)

    @property
    def tiles_touch(self) -> bool:
        """Whether another tile's edge lies just past each marker's quiet zone."""
        return self.polarity == "mixed" or self.board_type == "charuco"

    @property
    def extent_m(self) -> tuple[float, float, float, float]:
        """(x0, y0, x1, y1) of the printed pattern (without margin), board frame, metres."""
        if self.circles is not None:
            return self.circles.extent_m
        if self.chess is not None:
            return self.chess.extent_m
        w = self.cols * self.pitch - self.marker_separation
        h = self.rows * self.pitch - self.marker_separation
        if self.board_type == "aprilgrid":  # the corner squares around the outside
            s = self.marker_separation
            return -s, -s, w + s, h + s
        return 0.0, 0.0, w, h

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the printed pattern, outer edge to outer edge, metres."""
        x0, y0, x1, y1 = self.extent_m
        return x1 - x0, y1 - y0

    @property
    def margin_m(self) -> float:
        """Quiet margin printed around the pattern, metres."""
        if self.board_type in ("chessboard", "circles", "acircles"):
            return self.square_length
        if self.board_type == "charuco":
            return 0.5 * self.square_length
        return max(self.marker_separation, 2.0 * self.module_length)

    @property
    def finest_m(self) -> float:
        """The smallest feature of the print (a module, a square, a circle), metres."""
        if self.circles is not None:
            return 2.0 * self.circles.radius
        return self.square_length if self.board_type == "chessboard" else self.module_length

    @cached_property
    def ids(self) -> np.ndarray:
        """(N,) int: every marker id, row-major."""
        return np.arange(self.first_id, self.first_id + self.n_markers, dtype=np.int64)

    def has_id(self, marker_id: int) -> bool:
        """Whether ``marker_id`` belongs to this board."""
        return self.first_id <= marker_id < self.first_id + self.n_markers

    @cached_property
    def _marker_cells(self) -> np.ndarray:
        """(N, 2) int64 (row, col) of each marker: grid cell, or square of a ChArUco board."""
        if self.chess is not None:
            return self.chess.white_squares if self.n_markers else np.zeros((0, 2), np.int64)
        k = np.arange(self.n_markers)
        if self.board_type == "aprilgrid":
            return kalibr.tag_cells(k, self.cols, self.rows)
        return np.stack([k // self.cols, k % self.cols], axis=1)

    def cell_of(self, marker_id: int) -> tuple[int, int]:
        """(row, col) of a marker on the board; BoardError for an id not on it."""
        if not self.has_id(marker_id):
            last = f"{self.first_id}..{self.first_id + self.n_markers - 1}"
            raise BoardError(f"marker id {marker_id} is not on this board (ids {last})")
        r, c = self._marker_cells[marker_id - self.first_id]
        return int(r), int(c)

    def has_ids(self, marker_ids: np.ndarray) -> np.ndarray:
        """(N,) bool: which of ``marker_ids`` (N,) belong to this board."""
        k = np.asarray(marker_ids, dtype=np.int64).reshape(-1) - self.first_id
        return np.asarray((k >= 0) & (k < self.n_markers))

    def cells_of(self, marker_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rows (N,), cols (N,)) int64 of markers on the board; BoardError for ids not on it."""
        return self._cells(marker_ids)

    def _cells(self, marker_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        k = np.asarray(marker_ids, dtype=np.int64).reshape(-1) - self.first_id
        if k.size and (k.min() < 0 or k.max() >= self.n_markers):
            bad = np.asarray(marker_ids).reshape(-1)[(k < 0) | (k >= self.n_markers)]
            raise BoardError(f"marker ids {bad.tolist()} are not on this board")
        rc = self._marker_cells[k]
        return rc[:, 0], rc[:, 1]

    def marker_cells(self, marker_ids: np.ndarray) -> np.ndarray:
        """(N, 2) int64 (row, col) of markers: grid cells, or ChArUco squares."""
        rows, cols = self._cells(marker_ids)
        return np.stack([rows, cols], axis=1).reshape(-1, 2)

    def feature_cells(self, ids: np.ndarray) -> np.ndarray:
        """(K, 2) (row, col) of a view's correspondences: points, or markers on a grid."""
        return self.point_cells(ids) if self.has_points else self.marker_cells(ids)

    def object_corners(self, marker_ids: np.ndarray | None = None) -> np.ndarray:
        """(N, 4, 3) float64, metres: each marker's corners TL, TR, BR, BL in the board frame."""
        ids = self.ids if marker_ids is None else np.asarray(marker_ids)
        rows, cols = self._cells(ids)
        if self.chess is not None:
            q = self.quiet_zone_m
            x0, y0 = cols * self.square_length + q, rows * self.square_length + q
        else:
            x0, y0 = cols * self.pitch, rows * self.pitch
        L = self.marker_length
        out = np.zeros((len(rows), 4, 3))
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
        self.cell_of(marker_id)
        return self._marker_modules[marker_id - self.first_id]

    def is_white(self, x_m: np.ndarray, y_m: np.ndarray) -> np.ndarray:
        """Whether board points are printed white (vectorised, exact edges).

        Args:
            x_m, y_m: same-shape arrays of board-frame coordinates, metres.

        Returns:
            bool array of that shape. Points beyond the printed margin read as the
            background of the nearest tile (marker grid) or as white paper.
        """
        x = np.asarray(x_m, dtype=np.float64)
        y = np.asarray(y_m, dtype=np.float64)
        if self.circles is not None:
            return self.circles.is_white(x, y)
        if self.chess is not None:
            out = self.chess.squares_white(x, y)
            if not self.n_markers:
                return out
            row, col, inside = self.chess.square_of(x, y)
            k = np.where(inside, self.chess.marker_at_square[np.clip(row, 0, self.rows - 1),
                                                             np.clip(col, 0, self.cols - 1)], -1)
            q = self.quiet_zone_m
            u = x - col * self.square_length - q
            v = y - row * self.square_length - q
        else:
            half = 0.5 * self.marker_separation
            col = np.clip(np.floor((x + half) / self.pitch).astype(np.int64), 0, self.cols - 1)
            row = np.clip(np.floor((y + half) / self.pitch).astype(np.int64), 0, self.rows - 1)
            u = x - col * self.pitch
            v = y - row * self.pitch
            # Kalibr numbers an aprilgrid's tag rows from the bottom
            tag_row = (self.rows - 1 - row) if self.board_type == "aprilgrid" else row
            k = tag_row * self.cols + col
            inverted = np.array([self.is_inverted(int(i)) for i in self.ids], dtype=bool)
            out = ~inverted[k]  # tile background: white around a black marker
        inside = ((k >= 0) & (u >= 0) & (u < self.marker_length) & (v >= 0)
                  & (v < self.marker_length))
        n = self.bits + 2
        mc = np.clip((u[inside] / self.module_length).astype(np.int64), 0, n - 1)
        mr = np.clip((v[inside] / self.module_length).astype(np.int64), 0, n - 1)
        out[inside] = self._marker_modules[k[inside], mr, mc]
        if self.board_type == "aprilgrid":
            out &= ~kalibr.in_corner_square(x, y, self.cols, self.rows, self.marker_length,
                                            self.marker_separation)
        return out

    def print_lines(self) -> tuple[np.ndarray, np.ndarray]:
        """Sorted board x and y positions (metres) of every straight line the print may
        change colour on (:func:`artcal_ros.core.board.text.print_lines`)."""
        return print_lines(self)

    def to_cv_board(self) -> cv2.aruco.Board:
        """The equivalent OpenCV board (:func:`artcal_ros.core.board.text.cv_board`)."""
        return cv_board(self)

    def describe(self) -> str:
        """One line stating the board's parameters (printed on the board's margin)."""
        return describe(self)
