"""The calibration report a user reads: ``report.pdf`` and each page as a PNG, with
``summary.json`` beside them.

:func:`write_report` is the one entry point for a calibration (``artcal calibrate --report``
and the node after every successful solve); :func:`write_refused_report` for a set that gave
none. A calibration's pages, in order (PNG name in brackets):

1. the verdict in plain words and what to do if it is not good (``verdict.png``);
2. the residual vectors over the image, magnified, with the scale (``residuals.png``);
3. the residual histogram per point type (``residual_histogram.png``);
4. the projection uncertainty map with contours (``uncertainty.png``);
5. the distortion map: displacement from the pinhole image (``distortion.png``);
6. the coverage of every point used (``coverage.png``);
7. the error per picture, with the pictures left out and why (``per_view_error.png``);
8. the intrinsics with their standard deviations, the tone-curve and board checks in words
   (``intrinsics.png``).

A refused set has the verdict page (why, what to add) and the coverage of the points
detected. Every file is written whole under a temporary name and then renamed, so a reader
never sees half a report. Plots are drawn with matplotlib's Agg renderer: no display needed.
"""

from __future__ import annotations

import io
import json
import os
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.backends.backend_pdf import PdfPages
from matplotlib.figure import Figure

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.model import project
from artcal_ros.core.calibrate.report_pages import numbers_page, verdict_page
from artcal_ros.core.calibrate.report_plots import (
    coverage_figure,
    distortion_figure,
    histogram_figure,
    per_view_figure,
    residual_figure,
    uncertainty_figure,
)
from artcal_ros.core.calibrate.report_text import plain_verdict, refused_verdict
from artcal_ros.core.calibrate.result import CalibrationResult
from artcal_ros.core.calibrate.views import feature_term, lens_corrected_centers, view_points
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError

__all__ = ["PNG_DPI", "PdfReport", "calibration_pages", "point_kinds", "write_plots",
           "write_refused_report", "write_report", "write_summary"]

PNG_DPI = 100  # an 11 x 7.5 inch page is 1100 x 750 px
_KIND_NAMES = {"chessboard": "chessboard corners", "charuco": "ChArUco corners",
               "circles": "circle centres", "acircles": "circle centres"}


def _point_name(board: Board | None, points: str) -> str:
    if board is not None and board.board_type in _KIND_NAMES:
        return _KIND_NAMES[board.board_type]
    marker = "tag" if board is not None and board.board_type == "aprilgrid" else "marker"
    return f"{marker} {'centres' if points == 'centers' else 'corners'}"


def point_kinds(result: CalibrationResult,
                detections: Sequence[Detections | None] | None = None,
                board: Board | None = None) -> dict[str, np.ndarray]:
    """Residuals (N, 2) pixels by point type: the points solved from, and for a marker board
    (with ``detections``, the list the result's ``views_used`` index, and ``board``) the other
    type of point measured with the same camera and board poses."""
    used = _point_name(board, result.points)
    kinds = {f"{used} (solved from)": np.asarray(result.residuals_px)}
    if detections is None or board is None or board.has_points or not board.n_markers:
        return kinds
    other = "centers" if result.points == "corners" else "corners"
    cam = result.camera
    out = []
    for k, i in enumerate(result.views_used):
        if i >= len(detections):
            return kinds  # not the list the result was solved from
        det = detections[i]
        if det is None:
            continue
        v = view_points(det, board, other, i)
        if not len(v):
            continue
        if other == "centers":
            v = lens_corrected_centers(v, cam)
        predicted = project(v.object_points, result.rvecs[k], result.tvecs[k],
                            result.camera_matrix, result.dist_coeffs, result.model)
        out.append(v.image_points - predicted)
    if out:
        res = np.concatenate(out)
        # points the solve left out as outliers are not the other type's business either
        kinds[f"{_point_name(board, other)} (checked)"] = res[np.linalg.norm(res, axis=1) < 5.0]
    return kinds


def calibration_pages(result: CalibrationResult, *, tone_curve: Mapping[str, Any] | None = None,
                      board_check: Mapping[str, Any] | None = None,
                      detections: Sequence[Detections | None] | None = None,
                      board: Board | None = None, title: str = "",
                      first_page: bool = True) -> list[tuple[str, Figure]]:
    """The report's pages of a calibration: (PNG file name, figure), in order (see the module
    docstring); ``first_page`` False leaves out the verdict page (a rig's cameras)."""
    feature = feature_term(board) if board is not None else "markers"
    name = f"Calibration report: {title}" if title else "Camera calibration report"
    pages: list[tuple[str, Figure]] = []
    if first_page:
        verdict = plain_verdict(result, board_check=board_check, tone_curve=tone_curve,
                                feature=feature)
        pages.append(("verdict.png", verdict_page(verdict, name, result)))
    pages += [
        ("residuals.png", residual_figure(result)),
        ("residual_histogram.png", histogram_figure(point_kinds(result, detections, board))),
        ("uncertainty.png", uncertainty_figure(result)),
        ("distortion.png", distortion_figure(result)),
        ("coverage.png", coverage_figure(
            result.image_size, result.points_px,
            f"Coverage: every point used, from {len(result.views_used)} pictures",
            result.outliers_px)),
        ("per_view_error.png", per_view_figure(result)),
        ("intrinsics.png", numbers_page(result, tone_curve, board_check)),
    ]
    if title:
        for _, fig in pages[1 if first_page else 0:]:
            fig.text(0.96, 0.975, title, ha="right", va="top", fontsize=9, color="#666")
    return pages


def _replace_write(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` whole: a temporary file beside it, then a rename."""
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as e:
        raise ArtcalError(f"cannot write {path}: {e.strerror}") from None
    return path


class PdfReport:
    """report.pdf and the pages' PNGs of one report directory, written as pages are added;
    :meth:`close` puts the PDF in place."""

    def __init__(self, directory: str | Path, pdf_name: str = "report.pdf") -> None:
        self.directory = Path(directory).expanduser()
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ArtcalError(f"cannot write the report into {self.directory}: "
                              f"{e.strerror}") from None
        self.pdf_path = self.directory / pdf_name
        self._buffer = io.BytesIO()
        self._pdf = PdfPages(self._buffer, metadata={"Title": "Camera calibration report",
                                                     "Creator": "artcal_ros"})
        self.written: list[Path] = []
        self.pages = 0

    def add(self, figure: Figure, png_name: str | None) -> None:
        """One page; also ``png_name`` in the directory (a subfolder is made if named)."""
        self._pdf.savefig(figure)
        self.pages += 1
        if png_name:
            png = io.BytesIO()
            figure.savefig(png, format="png", dpi=PNG_DPI)
            path = self.directory / png_name
            path.parent.mkdir(parents=True, exist_ok=True)
            self.written.append(_replace_write(path, png.getvalue()))

    def close(self) -> list[Path]:
        """Write report.pdf; the paths written, the PDF first."""
        self._pdf.close()
        self.written.insert(0, _replace_write(self.pdf_path, self._buffer.getvalue()))
        return self.written


def write_summary(directory: Path, summary: Mapping[str, Any]) -> Path:
    """``directory``/summary.json, written whole."""
    return _replace_write(directory / "summary.json",
                          (json.dumps(summary, indent=1) + "\n").encode())


def write_report(directory: str | Path, result: CalibrationResult, *,
                 tone_curve: Mapping[str, Any] | None = None,
                 board_check: Mapping[str, Any] | None = None,
                 detections: Sequence[Detections] | None = None,
                 board: Board | None = None,
                 extra: Mapping[str, Any] | None = None,
                 title: str = "",
                 progress: Callable[[str], None] | None = None) -> list[Path]:
    """Write a calibration's report into ``directory`` (made if missing).

    ``summary.json`` (the result's summary with ``success`` true, ``tone_curve``,
    ``board_check`` and the ``extra`` keys), ``report.pdf`` and each page as a PNG (the module
    docstring lists them).

    Args:
        directory: where to write.
        result: the calibration.
        tone_curve: the tone curve used (``ToneEstimate.as_dict()``), if known.
        board_check: the board check (``BoardCheck.as_dict()``), if known.
        detections: the list the result was solved from (``views_used`` are positions in
            it) and ``board``: with both, the histogram also checks the other type of point
            of a marker board, and the advice names the board's features.
        extra: more keys for summary.json.
        title: the report's title (e.g. the camera's name).
        progress: called before each page with its PNG's name; may raise to stop (the
            report.pdf already there is then left as it was).

    Returns:
        The files written: report.pdf, the PNGs, summary.json.

    Raises:
        ArtcalError: the directory or a file cannot be written.
    """
    out = Path(directory).expanduser()
    summary: dict[str, Any] = {"success": True, **result.to_summary_dict()}
    if tone_curve is not None:
        summary["tone_curve"] = dict(tone_curve)
    if board_check is not None:
        summary["board_check"] = dict(board_check)
    summary.update(extra or {})
    report = PdfReport(out)
    for png, fig in calibration_pages(result, tone_curve=tone_curve, board_check=board_check,
                                      detections=detections, board=board, title=title):
        if progress is not None:
            progress(png or "page")  # may raise to stop: the PDF in place stays the old one
        report.add(fig, png)
    written = report.close()
    return [*written, write_summary(out, summary)]


def write_plots(directory: str | Path, result: CalibrationResult) -> list[Path]:
    """Only the PNGs of a calibration's pages (no PDF, no summary)."""
    out = Path(directory).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for png, fig in calibration_pages(result):
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=PNG_DPI)
        written.append(_replace_write(out / png, buf.getvalue()))
    return written


def write_refused_report(directory: str | Path, reason: str, image_size: tuple[int, int],
                         points_px: np.ndarray, *, images: int,
                         summary: Mapping[str, Any] | None = None,
                         title: str = "",
                         more_cameras: Mapping[str, tuple[tuple[int, int], np.ndarray]]
                         | None = None) -> list[Path]:
    """The report of a set that gave no calibration: report.pdf with the reason in words and
    the coverage of the points detected, ``verdict.png``, ``coverage.png`` and (given)
    ``summary`` as summary.json.

    Args:
        reason: why there is no calibration.
        image_size: (width, height), pixels.
        points_px: (P, 2) every board point detected, pixels.
        images: how many images were read (a rig: frames).
        title: the first camera's name for a rig (its coverage page then says so).
        more_cameras: a rig's other cameras: name -> (image size, points (P, 2)), each a
            coverage page and ``coverage_<name>.png``.
    """
    out = Path(directory).expanduser()
    cameras = {title: (image_size, points_px), **(more_cameras or {})}
    counted = {n: np.asarray(p, np.float64).reshape(-1, 2) for n, (_, p) in cameras.items()}
    report = PdfReport(out)
    heading = (f"Calibration report: {', '.join(cameras)}" if title
               else "Camera calibration report")
    report.add(verdict_page(refused_verdict(reason, images=images,
                                            points=sum(len(p) for p in counted.values())),
                            heading), "verdict.png")
    for k, (name, (size, _)) in enumerate(cameras.items()):
        whose = f" by {name}" if more_cameras else ""
        report.add(coverage_figure(size, counted[name],
                                   f"Coverage: every point detected{whose} in {images} "
                                   "pictures (no calibration)"),
                   "coverage.png" if k == 0 else f"coverage_{name}.png")
    written = report.close()
    if summary is not None:
        written.append(write_summary(out, summary))
    return written
