"""``artcal board``: write a printable board at exact physical scale.

    artcal board --params config/calibrator.yaml --out board.pdf
    artcal board --params config/boards/a4_5x7.yaml --out board.png --dpi 300
    artcal board --out board.svg --set board.cols=8 --set board.rows=6 --paper A3
    artcal board --size 8x6 --square 0.025 --out chess.pdf --paper A4  # camera_calibration's
    artcal board --pattern charuco --size 5x7 --square 0.04 --charuco_marker_size 0.03 \\
        --aruco_dict 6x6_250 --out charuco.pdf --paper A4
    artcal board --target april_6x6.yaml --out aprilgrid.pdf --paper A0   # a Kalibr target

The format follows the extension of ``--out`` (.pdf, .svg or .png). PDF and SVG
are vectors in millimetres; the PNG records its dpi. The page carries the
board's parameters and a 100 mm scale bar: measure it after printing. On a named
``--paper`` the board goes portrait or landscape, or turned a quarter turn with a narrower
white margin, whichever fits; the command says which.
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
from artcal_ros.core.board.paper import PAGE_BORDER_MM, PAPERS
from artcal_ros.core.board.printable import PageLayout, write_printable


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
                             "the board is centred on, portrait or landscape, turned a quarter "
                             "turn with a narrower white margin if that is what fits")


def run(args: argparse.Namespace) -> int:
    """Write the board; print where it went, the page and the board's size."""
    board = Board.from_params(params_from_args(args, board_overrides(args)))
    paper = None if args.paper == "fit" else args.paper
    layout = write_printable(board, args.out, dpi=args.dpi, paper=paper)
    print(f"wrote {args.out}: {page_text(board, layout, paper, args.dpi, args.out)}; "
          f"{board.describe()}")
    return 0


def page_text(board: Board, layout: PageLayout, paper: str | None, dpi: float,
              out: str) -> str:
    """The page in words: its size and orientation, and how the board was turned or its
    margin narrowed to fit the paper (the board's own size is in its description)."""
    w, h = layout.page_size_mm
    page = f"page {w:.1f} x {h:.1f} mm"
    if paper is not None:
        page = f"{paper} {'landscape' if w > h else 'portrait'}, {page}"
    if str(out).lower().endswith(".png"):
        page += f" at {dpi:g} dpi"
    if layout.turned:
        page += ", board turned a quarter turn to fit (its rows run down the page)"
    if layout.margin_mm < 1000.0 * board.margin_m - 1e-9:
        white = round(layout.margin_mm + PAGE_BORDER_MM, 1)
        full = round(1000.0 * board.margin_m + PAGE_BORDER_MM, 1)
        page += f", {white:g} mm of white around it (narrowed from {full:g} mm to fit)"
    return page
