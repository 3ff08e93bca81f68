"""``artcal board``: write a printable board at exact physical scale.

    artcal board --params config/calibrator.yaml --out board.pdf
    artcal board --params config/boards/a4_5x7.yaml --out board.png --dpi 300
    artcal board --out board.svg --set board.cols=8 --set board.rows=6 --paper A3
    artcal board --size 8x6 --square 0.03 --out chess.pdf        # camera_calibration's names
    artcal board --target april_6x6.yaml --out aprilgrid.pdf --paper A0   # a Kalibr target

The format follows the extension of ``--out`` (.pdf, .svg or .png). PDF and SVG
are vectors in millimetres; the PNG records its dpi. The page carries the
board's parameters and a 100 mm scale bar: measure it after printing.
"""

from __future__ import annotations

import argparse

from artcal_ros.cli.common import (
    add_board_arguments,
    add_params_arguments,
    board_overrides,
    params_from_args,
)
from artcal_ros.core.board import Board
from artcal_ros.core.printable import PAPERS, write_printable


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``artcal board``."""
    add_params_arguments(parser)
    add_board_arguments(parser)
    parser.add_argument("--out", required=True, metavar="FILE",
                        help="output file: board.pdf, board.svg or board.png")
    parser.add_argument("--dpi", type=float, default=300.0,
                        help="PNG resolution in dots per inch (default 300)")
    parser.add_argument("--paper", default="fit", choices=["fit", *PAPERS],
                        help="page size: fit (the board plus a border, default) or a paper "
                             "size the board is centred on")


def run(args: argparse.Namespace) -> int:
    """Write the board; print where it went and its size."""
    board = Board.from_params(params_from_args(args, board_overrides(args)))
    layout = write_printable(board, args.out, dpi=args.dpi,
                             paper=None if args.paper == "fit" else args.paper)
    w, h = layout.page_size_mm
    extra = f" at {args.dpi:g} dpi" if str(args.out).lower().endswith(".png") else ""
    print(f"wrote {args.out}: page {w:.1f} x {h:.1f} mm{extra}; {board.describe()}")
    return 0
