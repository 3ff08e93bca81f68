"""Printable boards: every marker detected back at its place, exact physical scale.

The reference is OpenCV's own ArUco detector and the board's object points
scaled by dpi / 25.4 mm; none of it goes through the renderer's geometry code.
"""

from __future__ import annotations

import re
import shutil
import struct
import subprocess
import xml.etree.ElementTree as ET
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from artcal_ros import Board
from artcal_ros.cli import main as cli
from artcal_ros.core.board.printable import PAGE_BORDER_MM, layout_page, write_printable

MIXED = Board(cols=4, rows=3, marker_length=0.04, marker_separation=0.02, first_id=100,
              polarity="mixed")


def _expected_origin_mm(board: Board) -> np.ndarray:
    # Page border, then the board's quiet margin: where the top-left marker's outer corner sits.
    return np.full(2, PAGE_BORDER_MM + 1000.0 * board.margin_m)


def _detect_all(board: Board, img: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(ids, corners (N, 4, 2)) of every board marker, each found in the pass for its polarity."""
    found: dict[int, np.ndarray] = {}
    for inverted in (False, True):
        p = cv2.aruco.DetectorParameters()
        p.detectInvertedMarker = inverted
        p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        corners, ids, _ = cv2.aruco.ArucoDetector(board.dictionary, p).detectMarkers(img)
        for c, i in zip(corners, [] if ids is None else ids.ravel(), strict=True):
            # With inversion on, OpenCV also reports some black markers with a shrunken quad;
            # each marker is taken only from the pass that matches how it is printed.
            if board.has_id(int(i)) and board.is_inverted(int(i)) == inverted:
                found[int(i)] = c.reshape(4, 2)
    ids = np.array(sorted(found), dtype=np.int64)
    return ids, np.array([found[i] for i in ids]).reshape(-1, 4, 2)


def _check_detected(board: Board, img: np.ndarray, dpi: float, origin_mm: np.ndarray,
                    center_tol_px: float, corner_tol_px: float) -> None:
    ids, corners = _detect_all(board, img)
    np.testing.assert_array_equal(ids, board.ids)   # every id, nothing else
    scale = dpi / 25.4
    # OpenCV pixel convention: the page's top-left corner is at (-0.5, -0.5).
    want_corners = (board.object_corners(ids)[:, :, :2] * 1000.0 + origin_mm) * scale - 0.5
    want_centers = (board.object_centers(ids)[:, :2] * 1000.0 + origin_mm) * scale - 0.5
    center_err = np.linalg.norm(corners.mean(axis=1) - want_centers, axis=1)
    corner_err = np.linalg.norm(corners - want_corners, axis=2)
    assert center_err.max() < center_tol_px, f"centre off by {center_err.max():.3f} px"
    assert corner_err.max() < corner_tol_px, f"corner off by {corner_err.max():.3f} px"


def _png_chunks(data: bytes) -> dict[bytes, list[bytes]]:
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    chunks: dict[bytes, list[bytes]] = {}
    pos = 8
    while pos < len(data):
        (length,) = struct.unpack(">I", data[pos:pos + 4])
        kind, body = data[pos + 4:pos + 8], data[pos + 8:pos + 8 + length]
        (crc,) = struct.unpack(">I", data[pos + 8 + length:pos + 12 + length])
        assert crc == zlib.crc32(kind + body) & 0xFFFFFFFF, kind
        chunks.setdefault(kind, []).append(body)
        pos += 12 + length
    return chunks


@pytest.mark.parametrize(("board", "dpi"), [(Board(), 100.0), (MIXED, 150.0)],
                         ids=["default-19x9", "mixed-4x3"])
def test_png_detects_every_marker_where_the_board_puts_it(tmp_path: Path, board: Board,
                                                          dpi: float) -> None:
    out = tmp_path / "board.png"
    layout = write_printable(board, out, dpi=dpi)
    np.testing.assert_allclose(layout.board_origin_mm, _expected_origin_mm(board))
    img = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (round(layout.page_size_mm[1] * dpi / 25.4),
                         round(layout.page_size_mm[0] * dpi / 25.4))
    _check_detected(board, img, dpi, _expected_origin_mm(board), 0.3, 0.6)


def test_png_records_its_dpi_and_description(tmp_path: Path) -> None:
    out = tmp_path / "board.png"
    write_printable(MIXED, out, dpi=150.0)
    chunks = _png_chunks(out.read_bytes())
    x_ppm, y_ppm, unit = struct.unpack(">IIB", chunks[b"pHYs"][0])
    assert unit == 1  # metres
    assert x_ppm == y_ppm == round(150.0 / 0.0254)
    assert chunks[b"tEXt"][0].split(b"\0")[1].decode() == MIXED.describe()
    assert b"IEND" in chunks


@pytest.mark.parametrize("dpi", [100.0, 127.0])
def test_scale_bar_is_100_mm_at_the_stated_dpi(tmp_path: Path, dpi: float) -> None:
    out = tmp_path / "board.png"
    write_printable(MIXED, out, dpi=dpi)
    img = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    footer = img[int((PAGE_BORDER_MM + 1000 * (MIXED.size_m[1] + 2 * MIXED.margin_m))
                     * dpi / 25.4) + 2:]
    best = 0.0
    for row in footer:
        dark = np.concatenate([[False], row < 128, [False]])
        d = np.diff(dark.astype(np.int8))
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        if not starts.size:
            continue
        k = int(np.argmax(ends - starts))
        a, b = max(starts[k] - 1, 0), min(ends[k] + 1, row.size)
        best = max(best, float(np.sum(255.0 - row[a:b]) / 255.0))  # ink incl. partial edges
    assert best == pytest.approx(100.0 * dpi / 25.4, abs=0.5)


def test_svg_is_in_millimetres_and_draws_the_board(tmp_path: Path) -> None:
    out = tmp_path / "board.svg"
    layout = write_printable(MIXED, out)
    root = ET.parse(out).getroot()
    ns = "{http://www.w3.org/2000/svg}"
    w_mm, h_mm = (float(root.get(k, "").removesuffix("mm")) for k in ("width", "height"))
    assert root.get("width", "").endswith("mm") and root.get("height", "").endswith("mm")
    assert [float(v) for v in root.get("viewBox", "").split()] == pytest.approx([0, 0, w_mm,
                                                                                  h_mm])
    assert (w_mm, h_mm) == pytest.approx(layout.page_size_mm, abs=1e-3)
    texts = [t.text for t in root.iter(f"{ns}text")]
    assert MIXED.describe() in texts
    # Black area inside the board (quiet margin included) equals the board's own black area.
    rects = np.array([[float(v) for v in m] for m in re.findall(
        r"M([\d.]+) ([\d.]+)H([\d.]+)V([\d.]+)H[\d.]+Z", root.find(f"{ns}path").get("d"))])
    ox, oy = _expected_origin_mm(MIXED)
    mg = 1000 * MIXED.margin_m
    bw, bh = (1000 * v for v in MIXED.size_m)
    inside = (rects[:, 0] >= ox - mg - 1e-6) & (rects[:, 2] <= ox + bw + mg + 1e-6) & \
             (rects[:, 3] <= oy + bh + mg + 1e-6)
    r = rects[inside]
    area_svg = np.sum((r[:, 2] - r[:, 0]) * (r[:, 3] - r[:, 1]))
    step = 0.25  # mm; sample the board's colour on a fine grid
    xs = np.arange(-mg + step / 2, bw + mg, step) / 1000
    ys = np.arange(-mg + step / 2, bh + mg, step) / 1000
    black = ~MIXED.is_white(*np.meshgrid(xs, ys))
    area_truth = black.mean() * (bw + 2 * mg) * (bh + 2 * mg)
    # The board's edges lie on this grid's cell boundaries, so the sampled area is exact.
    assert area_svg == pytest.approx(area_truth, rel=1e-6)


def _pdf_objects(data: bytes) -> tuple[dict[int, bytes], list[int]]:
    """Parse the xref table; check each offset points at its object; return the objects."""
    assert data.startswith(b"%PDF-1.4\n")
    m = re.search(rb"startxref\s+(\d+)\s+%%EOF\s*$", data)
    assert m, "startxref missing"
    xref = int(m.group(1))
    assert data[xref:xref + 4] == b"xref"
    head = re.match(rb"xref\s+0 (\d+)\s+", data[xref:])
    assert head
    count = int(head.group(1))
    entries = data[xref + head.end():xref + head.end() + 20 * count]
    objects: dict[int, bytes] = {}
    offsets = []
    for num in range(1, count):
        entry = entries[20 * num:20 * num + 20]
        assert entry.endswith(b" n \n") or entry.endswith(b" n\r\n"), entry
        offset = int(entry[:10])
        offsets.append(offset)
        assert data[offset:].startswith(f"{num} 0 obj".encode()), f"object {num} not at offset"
        objects[num] = data[offset:data.index(b"endobj", offset)]
    return objects, offsets


def test_pdf_structure_and_physical_page_size(tmp_path: Path) -> None:
    out = tmp_path / "board.pdf"
    layout = write_printable(Board(), out)
    objects, _ = _pdf_objects(out.read_bytes())
    page = next(o for o in objects.values() if b"/Type /Page " in o)
    box = [float(v) for v in re.search(rb"/MediaBox \[([^\]]+)\]", page).group(1).split()]
    w_mm, h_mm = layout.page_size_mm
    assert box == pytest.approx([0, 0, w_mm * 72 / 25.4, h_mm * 72 / 25.4], abs=1e-3)
    stream = next(o for o in objects.values() if b"stream" in o)
    length = int(re.search(rb"/Length (\d+)", stream).group(1))
    body = stream[stream.index(b"stream\n") + 7:]
    content = zlib.decompress(body[:length])
    assert content.count(b" re") == len(layout.rects_mm)
    assert b"/Helvetica" in b"".join(objects.values())
    assert b"Tj" in content


@pytest.mark.skipif(shutil.which("pdftoppm") is None, reason="pdftoppm (poppler-utils) missing")
@pytest.mark.parametrize(("board", "dpi"), [(Board(), 72.0), (MIXED, 150.0)],
                         ids=["default-19x9", "mixed-4x3"])
def test_pdf_rasterises_to_a_detectable_board(tmp_path: Path, board: Board, dpi: float) -> None:
    out = tmp_path / "board.pdf"
    write_printable(board, out)
    subprocess.run(["pdftoppm", "-r", f"{dpi:g}", "-gray", "-png", "-singlefile",
                    str(out), str(tmp_path / "raster")], check=True, timeout=60)
    img = cv2.imread(str(tmp_path / "raster.png"), cv2.IMREAD_GRAYSCALE)
    _check_detected(board, img, dpi, _expected_origin_mm(board), 0.5, 1.0)


@pytest.fixture
def board_only_cli(monkeypatch: pytest.MonkeyPatch) -> None:
    # The real ``artcal`` entry point and its error handling, with only this verb registered.
    monkeypatch.setattr(cli, "VERBS", {"board": cli.VERBS["board"]})


@pytest.mark.parametrize(
    ("argv", "says"),
    [
        (["--out", "{tmp}/board.jpg"], "use a .pdf, .svg or .png"),
        (["--out", "{tmp}/board"], "use a .pdf, .svg or .png"),
        (["--out", "{tmp}/b.png", "--set", "board.cols=0"], "board.cols"),
        (["--out", "{tmp}/b.png", "--set", "board.marker_separation=0.001"],
         "board.marker_separation"),
        (["--out", "{tmp}/b.png", "--set", "board.polarity=grey"], "board.polarity"),
        (["--out", "{tmp}/b.png", "--dpi", "3"], "--dpi"),
        (["--out", "{tmp}/b.pdf", "--paper", "A4"], "--paper A4"),
    ],
)
def test_cli_refuses_bad_input_with_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                             board_only_cli: None, argv: list[str],
                                             says: str) -> None:
    code = cli.main(["board", *[a.format(tmp=tmp_path) for a in argv]])
    err = capsys.readouterr().err
    assert code == 2
    assert says in err and "Traceback" not in err and err.count("\n") == 1
    assert not any(tmp_path.iterdir())


def test_cli_writes_each_format(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                board_only_cli: None, params_file: Path) -> None:
    for name in ("b.pdf", "b.svg", "b.png"):
        code = cli.main(["board", "--params", str(params_file), "--out", str(tmp_path / name),
                         "--dpi", "20", "--set", "board.cols=5", "--set", "board.rows=4"])
        assert code == 0
        assert (tmp_path / name).stat().st_size > 1000
    assert "5x4" in capsys.readouterr().out


def test_example_board_files_fit_their_paper() -> None:
    from artcal_ros.core.params import load_params

    root = Path(__file__).resolve().parents[2] / "config" / "boards"
    files = sorted(root.glob("*.yaml"))
    assert files
    for f in files:
        paper = f.stem.split("_")[0].upper()
        board = Board.from_params(load_params(f))
        layout_page(board, paper=paper)   # raises if it does not fit
