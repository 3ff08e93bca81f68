"""Printable boards at exact physical scale: PDF, SVG and PNG.

A board is laid out on one page: the marker area with its quiet margin
(:attr:`Board.margin_m`), a white page border, and a footer holding the board's
parameters (:meth:`Board.describe`) and a 100 mm scale bar to check the print.
Everything black on the page is a set of disjoint axis-aligned rectangles in
millimetres (page frame: origin at the page's top-left corner, x right, y
down), derived from :meth:`Board.is_white`, and on a circle grid a set of
discs, so the three formats print the same board:

- PDF 1.4 and SVG: the rectangles as exact vectors, page size in mm
  (1 mm = 72/25.4 pt in the PDF); discs as SVG circles, and in the PDF as four
  cubic Bezier arcs each (radius exact at eight points, off by at most 0.027 %
  of the radius between them: 2 micrometres on a 8 mm disc);
- PNG: 8-bit grey at ``dpi`` with exact area coverage at straight edges (discs:
  coverage from 16 x 16 sub-pixels where an edge crosses a pixel), and the dpi
  recorded in the ``pHYs`` chunk so that image viewers and printers know the
  physical size.

In the PNG, a board point ``p`` (metres, board frame) lands at the OpenCV pixel
coordinate ``(origin_mm + 1000 p) * dpi / 25.4 - 0.5`` (see :func:`board_to_png_px`).
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.board.paper import (
    FOOTER_MM,
    PAGE_BORDER_MM,
    SCALE_BAR_MM,
    fit_paper,
    pattern_mm,
)
from artcal_ros.core.errors import ParameterError

MM_PER_INCH = 25.4
PT_PER_MM = 72.0 / MM_PER_INCH
SCALE_BAR_THICK_MM = 1.5
FORMATS = (".pdf", ".svg", ".png")
PRINT_NOTE = "Print at actual size (100 %, no fit-to-page). The bar must measure 100 mm."

# Helvetica advance widths (1/1000 em) for fitting text to the page width.
_HELVETICA = {**dict.fromkeys("ijl'", 222), **dict.fromkeys(" .,:;!/[]fIt", 278),
              **dict.fromkeys("-()r`", 333), **dict.fromkeys("*", 389),
              **dict.fromkeys("ckszvxyJ\"", 500), **dict.fromkeys("+=<>~", 584),
              **dict.fromkeys("FTZ", 611), **dict.fromkeys("ABEKPSVXY&", 667),
              **dict.fromkeys("wCDHNRU", 722), **dict.fromkeys("GOQ", 778),
              **dict.fromkeys("mM", 833), **dict.fromkeys("%", 889),
              **dict.fromkeys("W", 944), **dict.fromkeys("@", 1015)}


def text_width_mm(text: str, size_mm: float) -> float:
    """Width of ``text`` set in Helvetica at ``size_mm`` (em size), millimetres."""
    return sum(_HELVETICA.get(ch, 556) for ch in text) * size_mm / 1000.0


@dataclass(frozen=True)
class TextLine:
    """One line of Helvetica text: left end of its baseline and em size, mm."""

    x_mm: float
    y_mm: float
    size_mm: float
    text: str


@dataclass(frozen=True)
class PageLayout:
    """Everything drawn on the page, in millimetres (page frame, y down).

    Attributes:
        page_size_mm: (width, height) of the page.
        board_origin_mm: page position of the board frame's origin (marker grid: the
            top-left outer corner of marker ``first_id``; see docs/conventions.md).
        rects_mm: (K, 4) float64 black rectangles (x0, y0, x1, y1), disjoint.
        texts: the footer's text lines.
        scale_bar_mm: (x0, y0, x1, y1) of the 100 mm scale bar's main stroke.
        description: :meth:`Board.describe` of the board.
        discs_mm: (D, 3) float64 black discs (centre x, centre y, radius) of a circle grid.
        turned: the board is turned a quarter turn clockwise on the page (board x runs down
            the page, board y from right to left), to fit its paper.
        margin_mm: the quiet margin printed around the pattern (narrower than
            :attr:`Board.margin_m` where that was needed to fit the paper).
    """

    page_size_mm: tuple[float, float]
    board_origin_mm: tuple[float, float]
    rects_mm: np.ndarray
    texts: tuple[TextLine, ...]
    scale_bar_mm: tuple[float, float, float, float]
    description: str
    discs_mm: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    turned: bool = False
    margin_mm: float = 0.0


def board_black_rects_m(board: Board) -> np.ndarray:
    """The board's black areas, quiet margin included, as disjoint rectangles.

    Every edge of the printed board lies on a module boundary, a marker edge or
    a tile boundary (midway across a gap), so the board is a grid of cells each
    of one colour (read from :meth:`Board.is_white`). Runs of black cells merge
    into rows, and rows with the same span into rectangles, which keeps vector
    files small.

    Returns:
        (K, 4) float64 (x0, y0, x1, y1), metres, board frame (none for a circle grid: its
        black is discs).
    """
    if board.circles is not None:
        return np.zeros((0, 4))
    margin = board.margin_m
    x0, y0, x1, y1 = board.extent_m
    lines = board.print_lines()
    xs = np.unique(np.round(np.concatenate([lines[0], [x0 - margin, x1 + margin]]), 12))
    ys = np.unique(np.round(np.concatenate([lines[1], [y0 - margin, y1 + margin]]), 12))
    cx, cy = 0.5 * (xs[1:] + xs[:-1]), 0.5 * (ys[1:] + ys[:-1])
    black = ~board.is_white(*np.meshgrid(cx, cy))       # (rows of cells, cols of cells)
    rects: list[tuple[float, float, float, float]] = []
    open_runs: dict[tuple[int, int], int] = {}          # (a, b) column span -> first cell row
    for r in range(black.shape[0] + 1):
        runs: set[tuple[int, int]] = set()
        if r < black.shape[0]:
            d = np.diff(np.concatenate([[0], black[r].astype(np.int8), [0]]))
            runs = set(zip(np.flatnonzero(d == 1).tolist(), np.flatnonzero(d == -1).tolist(),
                           strict=True))
        for span in [s for s in open_runs if s not in runs]:
            r0 = open_runs.pop(span)
            rects.append((xs[span[0]], ys[r0], xs[span[1]], ys[r]))
        for span in runs:
            open_runs.setdefault(span, r)
    return np.array(sorted(rects, key=lambda t: (t[1], t[0])), dtype=np.float64).reshape(-1, 4)


def layout_page(board: Board, *, paper: str | None = None) -> PageLayout:
    """Lay the board, its description and the scale bar out on one page.

    Args:
        board: the board to print.
        paper: None to size the page to its content, or a paper name
            (:data:`artcal_ros.core.board.paper.PAPERS`): portrait or landscape, the board turned
            a quarter turn and its quiet margin narrowed if that is what fits
            (:func:`artcal_ros.core.board.paper.fit_paper`); content centred.

    Raises:
        ParameterError: the board does not fit on ``paper``.
    """
    turned, margin_mm = False, board.margin_m * 1000.0
    if paper is not None:
        page_size, turned, margin_mm = fit_paper(board, paper)
    pattern_w, pattern_h = pattern_mm(board, turned)
    area_w, area_h = pattern_w + 2 * margin_mm, pattern_h + 2 * margin_mm
    content_w = max(area_w, SCALE_BAR_MM + 30.0)
    content_h = area_h + FOOTER_MM
    if paper is None:
        page_size = (content_w + 2 * PAGE_BORDER_MM, content_h + 2 * PAGE_BORDER_MM)
    page_w, page_h = page_size
    left = 0.5 * (page_w - content_w)
    top = 0.5 * (page_h - content_h)
    area_x = left + 0.5 * (content_w - area_w)
    x0, y0, x1, y1 = (1000.0 * v for v in board.extent_m)
    # The board's black, cut to the margin printed (board frame, mm).
    rects = board_black_rects_m(board) * 1000.0
    rects = np.column_stack([np.maximum(rects[:, 0], x0 - margin_mm),
                             np.maximum(rects[:, 1], y0 - margin_mm),
                             np.minimum(rects[:, 2], x1 + margin_mm),
                             np.minimum(rects[:, 3], y1 + margin_mm)])
    rects = rects[(rects[:, 2] > rects[:, 0]) & (rects[:, 3] > rects[:, 1])]
    if turned:   # board x runs down the page, board y from right to left
        origin = (area_x + margin_mm + y1, top + margin_mm - x0)
    else:
        origin = (area_x + margin_mm - x0, top + margin_mm - y0)
    board_rects = _board_rects_on_page(rects, origin, turned)

    # Footer: description, print note, then the scale bar with 10 mm ticks.
    foot_y = top + area_h
    size = min(3.0, content_w / max(text_width_mm(board.describe(), 1.0), 1e-9))
    texts: tuple[TextLine, ...] = (
        TextLine(left, foot_y + 5.0, size, board.describe()),
        TextLine(left, foot_y + 9.5, min(size, 2.5), PRINT_NOTE))
    bar = (left, foot_y + 13.0, left + SCALE_BAR_MM, foot_y + 13.0 + SCALE_BAR_THICK_MM)
    tick_w = 0.3
    ticks = []
    for k in range(11):
        x = min(max(bar[0] + 10.0 * k - 0.5 * tick_w, bar[0]), bar[2] - tick_w)
        ticks.append((x, bar[3], x + tick_w, bar[3] + (2.5 if k in (0, 5, 10) else 1.2)))
    texts += (TextLine(bar[2] + 3.0, bar[3] + 1.0, 3.0, "100 mm"),)
    all_rects = np.vstack([board_rects, np.array([bar, *ticks], dtype=np.float64)])
    discs = np.zeros((0, 3))
    if board.circles is not None:
        centres = _board_points_on_page(board.object_points()[:, :2] * 1000.0, origin, turned)
        discs = np.column_stack([centres, np.full(len(centres), board.circles.radius * 1000)])
    return PageLayout((page_w, page_h), origin, all_rects, texts, bar, board.describe(), discs,
                      turned=turned, margin_mm=margin_mm)


def _board_points_on_page(points_mm: np.ndarray, origin: tuple[float, float],
                          turned: bool) -> np.ndarray:
    """(N, 2) board-frame points (mm) -> page positions (mm)."""
    p = np.asarray(points_mm, dtype=np.float64)[:, :2]
    if turned:
        return np.column_stack([origin[0] - p[:, 1], origin[1] + p[:, 0]])
    return p + np.array(origin)


def _board_rects_on_page(rects_mm: np.ndarray, origin: tuple[float, float],
                         turned: bool) -> np.ndarray:
    """(K, 4) board-frame rectangles (x0, y0, x1, y1, mm) -> page rectangles (mm)."""
    lo = _board_points_on_page(rects_mm[:, :2], origin, turned)
    hi = _board_points_on_page(rects_mm[:, 2:], origin, turned)
    return np.column_stack([np.minimum(lo, hi), np.maximum(lo, hi)]).reshape(-1, 4)


def board_to_png_px(layout: PageLayout, points_m: np.ndarray, dpi: float) -> np.ndarray:
    """Where board points land in the PNG rendered at ``dpi``.

    Args:
        points_m: (N, 2) or (N, 3) float64, board frame, metres (z ignored).

    Returns:
        (N, 2) float64, OpenCV pixel coordinates (centre of the top-left pixel = (0, 0)).
    """
    p = _board_points_on_page(np.asarray(points_m, dtype=np.float64)[:, :2] * 1000.0,
                              layout.board_origin_mm, layout.turned)
    return p * (dpi / MM_PER_INCH) - 0.5


# --- PNG ----------------------------------------------------------------------------
def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return (struct.pack(">I", len(data)) + kind + data
            + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF))


def _coverage(a: float, b: float, lo: int, hi: int) -> tuple[int, np.ndarray]:
    """Fraction of each pixel i in [lo, hi) covered by [a, b) (pixel i spans [i, i+1))."""
    i0, i1 = max(lo, math.floor(a)), min(hi, math.ceil(b))
    if i1 <= i0:
        return i0, np.zeros(0, np.float32)
    i = np.arange(i0, i1, dtype=np.float64)
    return i0, (np.minimum(b, i + 1) - np.maximum(a, i)).clip(0.0, 1.0).astype(np.float32)


def _text_layer(layout: PageLayout, dpi: float, width: int) -> tuple[int, np.ndarray]:
    """The footer's text drawn with OpenCV's Hershey font: (first row, (h, width) uint8)."""
    s = dpi / MM_PER_INCH
    top = int(min(t.y_mm - t.size_mm for t in layout.texts) * s) - 2
    bottom = math.ceil(max(t.y_mm + 0.3 * t.size_mm for t in layout.texts) * s) + 2
    img = np.full((bottom - top, width), 255, np.uint8)
    font = cv2.FONT_HERSHEY_SIMPLEX
    for t in layout.texts:
        (w1, h1), _ = cv2.getTextSize(t.text, font, 1.0, 1)
        scale = min(0.72 * t.size_mm * s / h1,
                    text_width_mm(t.text, t.size_mm) * s / max(w1, 1))
        thick = max(1, round(scale * 1.6))
        org = (round(t.x_mm * s), round(t.y_mm * s) - top)
        cv2.putText(img, t.text, org, font, scale, 0, thick, cv2.LINE_AA)
    return top, img


_DISC_SUB = 16


def _disc_ink(ink: np.ndarray, cx: float, cy: float, r: float) -> None:
    """Add a disc's coverage to ``ink`` (h, w); centre (cx, cy) and radius r in pixel units
    where pixel (i, j) spans [j, j + 1) x [i, i + 1). Pixels an edge crosses are split into
    16 x 16 sub-pixels."""
    h, w = ink.shape
    i0, i1 = max(0, math.floor(cy - r)), min(h, math.ceil(cy + r))
    j0, j1 = max(0, math.floor(cx - r)), min(w, math.ceil(cx + r))
    if i1 <= i0 or j1 <= j0:
        return
    ii, jj = np.mgrid[i0:i1, j0:j1].astype(np.float64)
    d = np.hypot(jj + 0.5 - cx, ii + 0.5 - cy)
    cover = (d <= r - 0.75).astype(np.float32)      # wholly inside (half diagonal < 0.75)
    edge = np.abs(d - r) < 0.75
    if edge.any():
        sub = (np.arange(_DISC_SUB) + 0.5) / _DISC_SUB
        ex, ey = jj[edge][:, None, None] + sub[None, None, :], ii[edge][:, None, None] + sub[
            None, :, None]
        cover[edge] = np.mean(np.hypot(ex - cx, ey - cy) <= r, axis=(1, 2))
    ink[i0:i1, j0:j1] += cover


def png_rows(layout: PageLayout, dpi: float, band: int = 256) -> Iterator[np.ndarray]:
    """The page rendered at ``dpi``, as successive bands of rows ((h, W) uint8, white = 255).

    Banded so that a large board at a high dpi never needs the whole page in memory.
    """
    s = dpi / MM_PER_INCH
    width = round(layout.page_size_mm[0] * s)
    height = round(layout.page_size_mm[1] * s)
    rects = layout.rects_mm * s
    text_top, text = _text_layer(layout, dpi, width)
    for r0 in range(0, height, band):
        r1 = min(height, r0 + band)
        ink = np.zeros((r1 - r0, width), np.float32)
        for x0, y0, x1, y1 in rects[(rects[:, 3] > r0) & (rects[:, 1] < r1)]:
            ra, cy = _coverage(y0, y1, r0, r1)
            ca, cx = _coverage(x0, x1, 0, width)
            ink[ra - r0:ra - r0 + cy.size, ca:ca + cx.size] += cy[:, None] * cx[None, :]
        for cx, cy, r in layout.discs_mm[(layout.discs_mm[:, 1] + layout.discs_mm[:, 2]) * s
                                         > r0] * s:
            if cy - r < r1:
                _disc_ink(ink, cx, cy - r0, r)
        grey = np.rint(255.0 * (1.0 - np.clip(ink, 0.0, 1.0))).astype(np.uint8)
        a, b = max(r0, text_top), min(r1, text_top + text.shape[0])
        if a < b:
            grey[a - r0:b - r0] = np.minimum(grey[a - r0:b - r0], text[a - text_top:b - text_top])
        yield grey


def render_png(layout: PageLayout, dpi: float = 300.0) -> bytes:
    """An 8-bit grey PNG of the page with ``dpi`` recorded in its pHYs chunk."""
    s = dpi / MM_PER_INCH
    width = round(layout.page_size_mm[0] * s)
    height = round(layout.page_size_mm[1] * s)
    ppm = round(dpi / 0.0254)   # pHYs stores pixels per metre
    out = [b"\x89PNG\r\n\x1a\n",
           _png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)),
           _png_chunk(b"pHYs", struct.pack(">IIB", ppm, ppm, 1)),
           _png_chunk(b"tEXt", b"Description\x00" + layout.description.encode("latin-1"))]
    z = zlib.compressobj(6)
    for rows in png_rows(layout, dpi):
        filtered = np.zeros((rows.shape[0], rows.shape[1] + 1), np.uint8)  # filter 0 per row
        filtered[:, 1:] = rows
        data = z.compress(filtered.tobytes())
        if data:
            out.append(_png_chunk(b"IDAT", data))
    out.append(_png_chunk(b"IDAT", z.flush()))
    out.append(_png_chunk(b"IEND", b""))
    return b"".join(out)


# --- SVG ----------------------------------------------------------------------------
def _xml_escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def render_svg(layout: PageLayout) -> str:
    """The page as SVG, user units = millimetres (width/height in mm, matching viewBox)."""
    w, h = layout.page_size_mm
    path = " ".join(f"M{x0:.4f} {y0:.4f}H{x1:.4f}V{y1:.4f}H{x0:.4f}Z"
                    for x0, y0, x1, y1 in layout.rects_mm)
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{w:.4f}mm" height="{h:.4f}mm" '
        f'viewBox="0 0 {w:.4f} {h:.4f}">',
        f"<title>{_xml_escape(layout.description)}</title>",
        f'<rect x="0" y="0" width="{w:.4f}" height="{h:.4f}" fill="#ffffff"/>',
        # One path: abutting rectangles fill as one shape, with no anti-aliased seams.
        f'<path fill="#000000" d="{path}"/>',
    ]
    lines += [f'<circle cx="{x:.4f}" cy="{y:.4f}" r="{r:.4f}" fill="#000000"/>'
              for x, y, r in layout.discs_mm]
    lines += [f'<text x="{t.x_mm:.4f}" y="{t.y_mm:.4f}" font-family="Helvetica, Arial, '
              f'sans-serif" font-size="{t.size_mm:.4f}" fill="#000000">'
              f"{_xml_escape(t.text)}</text>" for t in layout.texts]
    lines.append("</svg>")
    return "\n".join(lines) + "\n"


# --- PDF ----------------------------------------------------------------------------
def _pdf_string(text: str) -> bytes:
    raw = text.encode("latin-1", errors="replace")
    return b"(" + raw.replace(b"\\", b"\\\\").replace(b"(", b"\\(").replace(b")", b"\\)") + b")"


def render_pdf(layout: PageLayout) -> bytes:
    """The page as a one-page PDF 1.4, MediaBox = the physical page size in points."""
    w_pt, h_pt = (v * PT_PER_MM for v in layout.page_size_mm)
    k = PT_PER_MM
    # Draw in mm with y down; one fill of all rectangles so that they merge without seams.
    ops = [f"q {k:.6f} 0 0 {-k:.6f} 0 {h_pt:.4f} cm 0 g".encode()]
    ops += [f"{x0:.4f} {y0:.4f} {x1 - x0:.4f} {y1 - y0:.4f} re".encode()
            for x0, y0, x1, y1 in layout.rects_mm]
    # a circle as four cubic Bezier quarter arcs (control points at 0.5523 r)
    kappa = 4.0 * (math.sqrt(2.0) - 1.0) / 3.0
    for x, y, r in layout.discs_mm:
        c = kappa * r
        ops.append((f"{x + r:.4f} {y:.4f} m "
                    f"{x + r:.4f} {y + c:.4f} {x + c:.4f} {y + r:.4f} {x:.4f} {y + r:.4f} c "
                    f"{x - c:.4f} {y + r:.4f} {x - r:.4f} {y + c:.4f} {x - r:.4f} {y:.4f} c "
                    f"{x - r:.4f} {y - c:.4f} {x - c:.4f} {y - r:.4f} {x:.4f} {y - r:.4f} c "
                    f"{x + c:.4f} {y - r:.4f} {x + r:.4f} {y - c:.4f} {x + r:.4f} {y:.4f} c h"
                    ).encode())
    ops.append(b"f Q")
    for t in layout.texts:
        ops.append(f"BT /F1 {t.size_mm * k:.3f} Tf 1 0 0 1 {t.x_mm * k:.4f} "
                   f"{h_pt - t.y_mm * k:.4f} Tm ".encode() + _pdf_string(t.text) + b" Tj ET")
    content = zlib.compress(b"\n".join(ops) + b"\n", 9)
    objects = [
        b"<< /Type /Catalog /Pages 2 0 R >>",
        b"<< /Type /Pages /Kids [3 0 R] /Count 1 >>",
        f"<< /Type /Page /Parent 2 0 R /MediaBox [0 0 {w_pt:.4f} {h_pt:.4f}] "
        f"/Resources << /Font << /F1 5 0 R >> >> /Contents 4 0 R >>".encode(),
        f"<< /Length {len(content)} /Filter /FlateDecode >>\nstream\n".encode()
        + content + b"\nendstream",
        b"<< /Type /Font /Subtype /Type1 /BaseFont /Helvetica /Encoding /WinAnsiEncoding >>",
        b"<< /Title " + _pdf_string(layout.description) + b" /Producer (artcal_ros) >>",
    ]
    out = bytearray(b"%PDF-1.4\n%\xe2\xe3\xcf\xd3\n")
    offsets = []
    for i, body in enumerate(objects, start=1):
        offsets.append(len(out))
        out += f"{i} 0 obj\n".encode() + body + b"\nendobj\n"
    xref = len(out)
    out += f"xref\n0 {len(objects) + 1}\n0000000000 65535 f \n".encode()
    out += b"".join(f"{o:010d} 00000 n \n".encode() for o in offsets)
    out += (f"trailer\n<< /Size {len(objects) + 1} /Root 1 0 R /Info {len(objects)} 0 R >>\n"
            f"startxref\n{xref}\n%%EOF\n").encode()
    return bytes(out)


def write_printable(board: Board, path: str | Path, *, dpi: float = 300.0,
                    paper: str | None = None) -> PageLayout:
    """Write the printable board to ``path``; the format follows its extension.

    Args:
        board: the board to print.
        path: ``*.pdf``, ``*.svg`` or ``*.png``.
        dpi: PNG resolution, dots per inch (ignored for the vector formats).
        paper: see :func:`layout_page`.

    Returns:
        The page layout (where the board sits on the page, in mm).

    Raises:
        ParameterError: unknown extension, bad dpi, or the board does not fit the paper.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ParameterError(f"--out {path}: unknown format {suffix or '(no extension)'!r}; "
                             "use a .pdf, .svg or .png file name")
    if not 10.0 <= dpi <= 2400.0:
        raise ParameterError(f"--dpi {dpi:g}: use a resolution between 10 and 2400 dots per inch")
    layout = layout_page(board, paper=paper)
    if suffix == ".png":
        data = render_png(layout, dpi)
    elif suffix == ".svg":
        data = render_svg(layout).encode("utf-8")
    else:
        data = render_pdf(layout)
    try:
        path.write_bytes(data)
    except OSError as e:
        raise ParameterError(f"--out {path}: cannot write: {e.strerror}") from None
    return layout
