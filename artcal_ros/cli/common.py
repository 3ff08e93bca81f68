"""Argument helpers shared by the ``artcal`` verbs."""

from __future__ import annotations

import argparse
from typing import Any

from artcal_ros.core.errors import ParameterError
from artcal_ros.core.kalibr_target import target_params
from artcal_ros.core.params import ParamValue, load_params, parse_override


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
    ``--size COLSxROWS --square METRES`` and Kalibr's ``--target target.yaml``."""
    parser.add_argument("--size", metavar="COLSxROWS", default=None,
                        help="a chessboard of COLS x ROWS inner corners, as camera_calibration's "
                             "--size 8x6 (sets board.type chessboard, board.cols, board.rows)")
    parser.add_argument("--square", type=float, default=None, metavar="METRES",
                        help="with --size: the chessboard's square side in metres, as "
                             "camera_calibration's --square 0.108 (board.square_length)")
    parser.add_argument("--target", metavar="target.yaml", default=None,
                        help="a Kalibr target YAML (target_type aprilgrid, checkerboard or "
                             "circlegrid), translated into the board.* parameters "
                             "(docs/conventions.md)")


def chessboard_overrides(size: str | None, square: float | None) -> dict[str, Any]:
    """camera_calibration's ``--size COLSxROWS --square METRES`` as ``board.*`` parameters.

    ``--size 8x6`` is a chessboard of 8 x 6 inner corners (board.type chessboard,
    board.cols 8, board.rows 6); ``--square 0.108`` its square side in metres
    (board.square_length).
    """
    out: dict[str, Any] = {}
    if size is not None:
        parts = size.lower().split("x")
        if len(parts) != 2 or not all(p.strip().isdigit() for p in parts):
            raise ParameterError(f"--size {size!r}: expected COLSxROWS of inner corners, "
                                 "e.g. --size 8x6")
        cols, rows = (int(p) for p in parts)
        if cols < 2 or rows < 2:
            raise ParameterError(f"--size {size}: a chessboard needs at least 2x2 inner corners")
        out.update({"board.type": "chessboard", "board.cols": cols, "board.rows": rows})
    if square is not None:
        if not square > 0:
            raise ParameterError(f"--square {square}: must be > 0 (metres)")
        if size is None:
            raise ParameterError("--square needs --size (camera_calibration's chessboard); "
                                 "for other boards use --set board.square_length=...")
        out["board.square_length"] = float(square)
    return out


def board_overrides(args: argparse.Namespace) -> dict[str, Any]:
    """The board a verb's own options give: ``--size``/``--square`` (camera_calibration's
    chessboard) or ``--target`` (a Kalibr target YAML), not both."""
    target = getattr(args, "target", None)
    if target is not None and (args.size is not None or args.square is not None):
        raise ParameterError("--target and --size/--square each give the board; give one")
    if target is not None:
        return target_params(target)
    return chessboard_overrides(args.size, args.square)
