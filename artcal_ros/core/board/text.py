"""The board in other words: the one-line description printed on it, and OpenCV's equivalent
board object. Functions of a :class:`~artcal_ros.core.board.Board` (its methods call them;
typed ``Any`` here because ``board`` imports this module)."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board.aprilgrid import describe as aprilgrid_describe
from artcal_ros.core.errors import BoardError


def cv_board(board: Any) -> cv2.aruco.Board:
    """The equivalent OpenCV board: ``GridBoard``, ``CharucoBoard``, or a general ``Board``
    for an aprilgrid (same ids and object points); BoardError for a chessboard, which OpenCV
    has no class for."""
    if board.board_type == "charuco":
        b = cv2.aruco.CharucoBoard((board.cols, board.rows), board.square_length,
                                   board.marker_length, board.dictionary,
                                   board.ids.astype(np.int32))
        b.setLegacyPattern(board.legacy_pattern)
        return b
    if board.board_type in ("chessboard", "circles", "acircles"):
        raise BoardError(f"a {board.board_type} board has no OpenCV board object; "
                         "use object_points()")
    if board.board_type == "aprilgrid":
        return cv2.aruco.Board(list(board.object_corners().astype(np.float32)),
                               board.dictionary, board.ids.astype(np.int32))
    return cv2.aruco.GridBoard((board.cols, board.rows), board.marker_length,
                               board.marker_separation, board.dictionary,
                               board.ids.astype(np.int32))


def describe(board: Any) -> str:
    """One line stating the board's parameters (printed on the board's margin)."""
    w, h = board.size_m
    size = f"({w * 1000:g} x {h * 1000:g} mm)"
    if board.board_type == "chessboard":
        return (f"artcal chessboard {board.cols}x{board.rows} inner corners "
                f"square {board.square_length * 1000:g} mm {size}")
    if board.board_type == "charuco":
        legacy = " legacy pattern" if board.legacy_pattern else ""
        return (f"artcal charuco {board.cols}x{board.rows} squares {board.dictionary_name} "
                f"ids {board.first_id}..{int(board.ids[-1])} "
                f"square {board.square_length * 1000:g} mm "
                f"marker {board.marker_length * 1000:g} mm{legacy} {size}")
    if board.circles is not None:
        kind = "asymmetric" if board.circles.asymmetric else "symmetric"
        return (f"artcal {board.board_type} {board.cols}x{board.rows} circles ({kind} grid) "
                f"spacing {board.square_length * 1000:g} mm "
                f"diameter {2000 * board.circles.radius:g} mm {size}")
    if board.board_type == "aprilgrid":
        return aprilgrid_describe(board.cols, board.rows, board.marker_length,
                               board.marker_separation, size)
    return (f"artcal marker_grid {board.cols}x{board.rows} {board.dictionary_name} "
            f"ids {board.first_id}..{int(board.ids[-1])} "
            f"marker {board.marker_length * 1000:g} mm "
            f"gap {board.marker_separation * 1000:g} mm polarity {board.polarity} "
            f"{size}")


def print_lines(board: Any) -> tuple[np.ndarray, np.ndarray]:
    """Sorted board x and y positions (metres) of every straight line the print may change
    colour on: module and marker edges, tile edges (midway across a gap), square edges.
    A circle grid has none (empty arrays): its edges are the circles."""
    if board.circles is not None:
        return np.zeros(0), np.zeros(0)
    lines: list[np.ndarray] = []
    n = board.bits + 2
    chess = board.chess.lines_m() if board.chess is not None else None
    for axis, count in enumerate((board.cols, board.rows)):
        parts: list[np.ndarray] = []
        starts: np.ndarray
        if chess is not None:
            parts.append(chess[axis])
            starts = chess[axis][:-1] + board.quiet_zone_m
        else:
            starts = np.arange(count) * board.pitch
            parts.append(starts[1:] - 0.5 * board.marker_separation)
            if board.board_type == "aprilgrid":  # the outer corner squares' edges
                s = board.marker_separation
                parts.append(np.array([-s, count * board.pitch]))
        if board.n_markers:
            parts.append((starts[:, None] + np.arange(n + 1) * board.module_length).ravel())
        lines.append(np.unique(np.round(np.concatenate(parts), 12)))
    return lines[0], lines[1]


def size_parameters(board: Any) -> str:
    """The parameters that set the board's geometry, for messages."""
    if board.board_type in ("chessboard", "circles", "acircles"):
        return "board.cols, board.rows, board.square_length"
    if board.board_type == "charuco":
        return "board.cols, board.rows, board.square_length, board.marker_length"
    if board.board_type == "aprilgrid":
        return ("board.cols, board.rows, board.marker_length (tagSize), "
                "board.marker_separation (tagSize x tagSpacing)")
    return "board.cols, board.rows, board.marker_length, board.marker_separation"
