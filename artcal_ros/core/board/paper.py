"""Which paper a printable board goes on, and which way round.

A page holds the pattern, its quiet margin, a white page border and a footer (the board's
parameters and a 100 mm scale bar) below the pattern. On a named paper the board's own
margin is kept when the page fits it portrait or landscape; otherwise the board is turned a
quarter turn and its margin narrowed, whichever leaves the most white around it.
"""

from __future__ import annotations

from artcal_ros.core.board import Board
from artcal_ros.core.errors import ParameterError

PAGE_BORDER_MM = 10.0    # white border: most printers cannot print to the paper's edge
FOOTER_MM = 20.0         # room for two text lines and the scale bar
SCALE_BAR_MM = 100.0
# (width, height) in mm, portrait
PAPERS: dict[str, tuple[float, float]] = {
    "A0": (841.0, 1189.0), "A1": (594.0, 841.0), "A2": (420.0, 594.0),
    "A3": (297.0, 420.0), "A4": (210.0, 297.0), "letter": (215.9, 279.4),
}

# A quiet margin may narrow to fit a paper, but the white around the pattern (margin and
# page border together) stays at least this fraction of the board's own margin: the outer
# squares of a chessboard and the border of a marker need white around them to be found.
MIN_WHITE_FRACTION = 0.5


def pattern_mm(board: Board, turned: bool) -> tuple[float, float]:
    """(width, height) of the printed pattern on the page, mm (swapped when turned)."""
    w, h = (1000.0 * v for v in board.size_m)
    return (h, w) if turned else (w, h)


def fit_paper(board: Board, paper: str) -> tuple[tuple[float, float], bool, float]:
    """Where the board goes on ``paper``: (page size mm, turned a quarter turn, margin mm).

    The board's own margin on a portrait, then a landscape page is preferred; else the
    placement (board turned or not, either page orientation) that leaves the widest margin,
    if that keeps the white around the pattern at :data:`MIN_WHITE_FRACTION` of it.
    """
    if paper not in PAPERS:
        raise ParameterError(f"--paper {paper!r}: use one of fit, {', '.join(PAPERS)}")
    pw, ph = PAPERS[paper]
    full = board.margin_m * 1000.0
    least = max(0.0, MIN_WHITE_FRACTION * full - PAGE_BORDER_MM)
    best: tuple[tuple[float, float], bool, float] | None = None
    for turned in (False, True):
        w, h = pattern_mm(board, turned)
        for page in ((pw, ph), (ph, pw)):
            room_w = page[0] - 2 * PAGE_BORDER_MM
            room_h = page[1] - 2 * PAGE_BORDER_MM - FOOTER_MM
            if room_w < SCALE_BAR_MM + 30.0:
                continue
            margin = min(full, 0.5 * (room_w - w), 0.5 * (room_h - h))
            if margin >= full:
                return page, turned, full
            if margin >= least and (best is None or margin > best[2]):
                best = (page, turned, margin)
    if best is None:
        w, h = pattern_mm(board, False)
        need_w = max(w + 2 * full, SCALE_BAR_MM + 30.0) + 2 * PAGE_BORDER_MM
        need_h = h + 2 * full + FOOTER_MM + 2 * PAGE_BORDER_MM
        length = ("marker_length" if board.chess is None and board.circles is None
                  else "square_length")
        raise ParameterError(
            f"--paper {paper}: the board needs {need_w:.0f} x {need_h:.0f} mm with its "
            f"border and footer ({w:.0f} x {h:.0f} mm without) but {paper} is {pw:g} x "
            f"{ph:g} mm either way round; use a larger paper, --paper fit, or a smaller "
            f"board.{length}")
    return best
