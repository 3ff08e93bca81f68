"""Argument helpers shared by the ``artcal`` verbs."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from artcal_ros.core.board.dictionaries import predefined_code
from artcal_ros.core.board.kalibr_target import target_params
from artcal_ros.core.errors import ParameterError
from artcal_ros.core.params import ParamValue, length_complaint, load_params, parse_override

# camera_calibration's --pattern values (its Patterns) and its board options, by dest name
PATTERNS = ("chessboard", "circles", "acircles", "charuco")
CAMERA_CALIBRATION_OPTIONS = ("pattern", "size", "square", "charuco_marker_size", "aruco_dict")


def add_params_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--params P`` and ``--set KEY=VALUE`` (repeatable)."""
    parser.add_argument("--params", metavar="P", default=None,
                        help="ROS 2 parameters file (e.g. config/calibrator.yaml)")
    parser.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                        help="override one parameter, e.g. --set board.cols=10 (repeatable)")


def params_from_args(args: argparse.Namespace,
                     extra: dict[str, Any] | None = None) -> dict[str, ParamValue]:
    """Parameters from ``--params`` with the ``--set`` overrides applied (validated).

    Args:
        extra: further overrides (from a verb's own options); a ``--set`` of the same
            parameter with another value is refused.
    """
    overrides: dict[str, Any] = dict(parse_override(s) for s in args.set)
    for key, value in (extra or {}).items():
        if key in overrides and overrides[key] != value:
            raise ParameterError(f"--set {key}={overrides[key]} contradicts {value!r} given "
                                 "by the command's own options; give one of them")
        overrides[key] = value
    return load_params(args.params, overrides)


def add_board_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the board options users bring from their home tools: camera_calibration's
    ``--pattern --size --square --charuco_marker_size --aruco_dict`` and Kalibr's
    ``--target target.yaml`` (docs/conventions.md has the mapping)."""
    group = parser.add_argument_group(
        "board, as camera_calibration or Kalibr gives it (instead of board.* parameters)")
    group.add_argument("--pattern", choices=PATTERNS, default=None,
                       help="camera_calibration's pattern (default chessboard); sets "
                            "board.type")
    group.add_argument("--size", metavar="COLSxROWS", default=None,
                       help="as camera_calibration's --size 8x6: inner corners (chessboard), "
                            "squares (charuco), circles (circles, acircles); sets board.cols, "
                            "board.rows; needs --square")
    group.add_argument("--square", type=float, default=None, metavar="METRES",
                       help="with --size: the square side in metres (circle grids: the "
                            "circle spacing), as camera_calibration's --square 0.108 "
                            "(board.square_length)")
    group.add_argument("--charuco_marker_size", type=float, default=None, metavar="METRES",
                       help="with --pattern charuco: the marker side in metres "
                            "(board.marker_length)")
    group.add_argument("--aruco_dict", default=None, metavar="DICT",
                       help="with --pattern charuco: camera_calibration's dictionary name "
                            "(6x6_250, aruco_orig, ...) or OpenCV's (DICT_6X6_250) "
                            "(board.dictionary)")
    group.add_argument("--target", metavar="target.yaml", default=None,
                       help="a Kalibr target YAML (target_type aprilgrid, checkerboard or "
                            "circlegrid), translated into the board.* parameters")


def length_option(flag: str, value: float | None) -> float | None:
    """A length given on the command line, in metres, checked for a plausible size."""
    if value is None:
        return None
    if not value > 0:
        raise ParameterError(f"{flag} {value:g}: must be > 0 (metres)")
    complaint = length_complaint(value)
    if complaint:
        raise ParameterError(f"{flag} {value:g}: {complaint}")
    return float(value)


def aruco_dict_name(value: str) -> str:
    """camera_calibration's ``--aruco_dict`` value (``6x6_250``, ``aruco_orig``) or OpenCV's
    name (``DICT_6X6_250``) as OpenCV's name."""
    text = value.strip()
    if text.lower() == "aruco_orig":
        name = "DICT_ARUCO_ORIGINAL"
    elif text.upper().startswith("DICT_"):
        name = text.upper()
    else:
        name = "DICT_" + text.upper()
    if predefined_code(name) is not None:
        return name
    raise ParameterError(f"--aruco_dict {value!r}: not an ArUco dictionary; use "
                         "camera_calibration's names (aruco_orig, 4x4_50 ... 7x7_1000, e.g. "
                         "6x6_250) or OpenCV's (DICT_6X6_250)")


def _parse_size(size: str, pattern: str) -> tuple[int, int]:
    what = {"chessboard": "inner corners", "charuco": "squares"}.get(pattern, "circles")
    parts = size.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
        raise ParameterError(f"--size {size!r}: expected COLSxROWS of {what}, e.g. --size 8x6")
    cols, rows = (int(p) for p in parts)
    if cols < 2 or rows < 2:
        raise ParameterError(f"--size {size}: a {pattern} needs at least 2x2 {what}")
    return cols, rows


def camera_calibration_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """camera_calibration's board options as ``board.*`` parameters.

    ``--pattern P --size COLSxROWS --square METRES`` give board.type, board.cols, board.rows
    and board.square_length (``--size`` counts what camera_calibration counts: inner corners
    of a chessboard, squares of a charuco board, circles of a grid); ``--pattern charuco``
    also needs ``--charuco_marker_size`` (board.marker_length) and ``--aruco_dict``
    (board.dictionary), as camera_calibration requires.
    """
    pattern = getattr(args, "pattern", None)
    size = getattr(args, "size", None)
    square = length_option("--square", getattr(args, "square", None))
    marker = length_option("--charuco_marker_size", getattr(args, "charuco_marker_size", None))
    dictionary = getattr(args, "aruco_dict", None)
    if all(v is None for v in (pattern, size, square, marker, dictionary)):
        return {}
    kind = pattern or "chessboard"
    if kind != "charuco":
        for flag, value in (("--charuco_marker_size", marker), ("--aruco_dict", dictionary)):
            if value is not None:
                raise ParameterError(f"{flag} is for --pattern charuco (camera_calibration's); "
                                     "for another board use --set board.marker_length=... or "
                                     "--set board.dictionary=...")
    if size is None:
        raise ParameterError(f"{'--pattern' if pattern else '--square'} needs --size COLSxROWS "
                             "and --square METRES (camera_calibration's board); for other "
                             "boards use --params or --set board.*=...")
    cols, rows = _parse_size(size, kind)
    if square is None:
        raise ParameterError(f"--size {size} needs --square METRES, the side of a square in "
                             "metres (circle grids: the spacing), e.g. --square 0.025")
    out: dict[str, Any] = {"board.type": kind, "board.cols": cols, "board.rows": rows,
                           "board.square_length": square}
    if kind == "charuco":
        missing = [f for f, v in (("--charuco_marker_size", marker), ("--aruco_dict", dictionary))
                   if v is None]
        if missing:
            raise ParameterError(f"--pattern charuco needs {' and '.join(missing)} too, as "
                                 "camera_calibration does (e.g. --charuco_marker_size 0.019 "
                                 "--aruco_dict 6x6_250)")
        out["board.marker_length"] = marker
        out["board.dictionary"] = aruco_dict_name(str(dictionary))
    return out


def board_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The board a verb's own options give: camera_calibration's (``--pattern``, ``--size``,
    ``--square``, ...) or ``--target`` (a Kalibr target YAML), not both."""
    target = getattr(args, "target", None)
    given = [f"--{name}" for name in CAMERA_CALIBRATION_OPTIONS
             if getattr(args, name, None) is not None]
    if target is not None and given:
        raise ParameterError(f"--target and {'/'.join(given)} each give the board; give one")
    if target is not None:
        return target_params(target)
    return camera_calibration_overrides(args)


def check_writable(flag: str, path: str) -> None:
    """Refuse, before any work, an output path whose nearest existing folder is no folder."""
    parent = Path(path).expanduser().absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not parent.is_dir():
        raise ParameterError(f"{flag} {path}: cannot write it: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ParameterError(f"{flag} {path}: cannot write it: {parent}: permission denied")
