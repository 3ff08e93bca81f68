"""Plots of a calibration, drawn with OpenCV (no plotting library needed).

- ``residuals.png``: every point's residual vector over the image, magnified; outliers
  that were dropped as red crosses.
- ``coverage.png``: where the points fall in the image, with the 8 x 6 coverage grid
  shaded by how many points each cell holds.
- ``per_view_error.png``: the RMS reprojection error of each view used, as bars.

A set that gave no calibration has only ``coverage.png``, of the points detected.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from artcal_ros.core.calibrate.result import CalibrationResult
from artcal_ros.core.calibrate.views import COVERAGE_GRID
from artcal_ros.core.errors import ArtcalError

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_BLACK = (0, 0, 0)
_GREY = (170, 170, 170)
_BLUE = (180, 90, 20)
_RED = (30, 30, 220)


def _canvas(image_size: tuple[int, int], width: int = 960,
            top: int = 40) -> tuple[np.ndarray, float, int]:
    """A white canvas showing the image frame: (canvas, pixels-per-image-pixel, top margin)."""
    w, h = image_size
    scale = width / w
    canvas = np.full((round(h * scale) + top + 10, width + 20, 3), 255, np.uint8)
    cv2.rectangle(canvas, (10, top), (10 + width, top + round(h * scale)), _BLACK, 1)
    return canvas, scale, top


def _to_canvas(points: np.ndarray, scale: float, top: int) -> np.ndarray:
    return np.column_stack([10 + points[:, 0] * scale, top + points[:, 1] * scale])


def residual_plot(result: CalibrationResult) -> np.ndarray:
    """BGR image of the residual vectors over the image."""
    canvas, scale, top = _canvas(result.image_size)
    norms = np.linalg.norm(result.residuals_px, axis=1)
    ref = float(np.percentile(norms, 95)) if len(norms) else 1.0
    gain = 15.0 / max(ref, 1e-6)  # the 95th percentile residual draws 15 canvas pixels
    start = _to_canvas(result.points_px, scale, top)
    end = start + result.residuals_px * gain
    for a, b in zip(start, end, strict=True):
        cv2.line(canvas, (round(a[0]), round(a[1])),
                 (round(b[0]), round(b[1])), _BLUE, 1, cv2.LINE_AA)
        cv2.circle(canvas, (round(a[0]), round(a[1])), 1, _BLACK, -1)
    for p in _to_canvas(result.outliers_px, scale, top):
        x, y = round(p[0]), round(p[1])
        cv2.line(canvas, (x - 4, y - 4), (x + 4, y + 4), _RED, 2)
        cv2.line(canvas, (x - 4, y + 4), (x + 4, y - 4), _RED, 2)
    text = (f"residuals x{gain:.0f}: RMS {result.reprojection_rms_px:.3f} px, max "
            f"{result.reprojection_max_px:.3f} px; {len(result.outliers_px)} outliers (red)")
    cv2.putText(canvas, text, (10, 27), _FONT, 0.6, _BLACK, 1, cv2.LINE_AA)
    return canvas


def coverage_plot(result: CalibrationResult) -> np.ndarray:
    """BGR image of the points over the image and the coverage grid."""
    gx, gy = COVERAGE_GRID
    text = (f"{len(result.points_px)} points from {len(result.views_used)} views; "
            f"{100 * result.coverage:.0f}% of the {gx}x{gy} grid covered (pink: empty)")
    return points_plot(result.image_size, result.points_px, text)


def points_plot(image_size: tuple[int, int], points_px: np.ndarray, text: str) -> np.ndarray:
    """BGR image of points over the image, the coverage grid shaded by how many each cell
    holds; ``points_px`` (P, 2) pixels, ``text`` the title."""
    canvas, scale, top = _canvas(image_size)
    w, h = image_size
    gx, gy = COVERAGE_GRID
    points_px = np.asarray(points_px, np.float64).reshape(-1, 2)
    points_px = points_px[np.all(np.isfinite(points_px), axis=1)]
    cx = np.clip((points_px[:, 0] / w * gx).astype(int), 0, gx - 1)
    cy = np.clip((points_px[:, 1] / h * gy).astype(int), 0, gy - 1)
    counts = np.zeros((gy, gx))
    np.add.at(counts, (cy, cx), 1)
    top_count = max(float(counts.max()), 1.0)
    for j in range(gy):
        for i in range(gx):
            x0, x1 = int(10 + i * w / gx * scale), int(10 + (i + 1) * w / gx * scale)
            y0, y1 = int(top + j * h / gy * scale), int(top + (j + 1) * h / gy * scale)
            if counts[j, i] == 0:
                colour = (210, 210, 255)  # empty cells in pink: nothing measured there
            else:
                g = int(255 - 90 * counts[j, i] / top_count)
                colour = (g, 255, g)
            cv2.rectangle(canvas, (x0, y0), (x1, y1), colour, -1)
            cv2.rectangle(canvas, (x0, y0), (x1, y1), _GREY, 1)
    for p in _to_canvas(points_px, scale, top):
        cv2.circle(canvas, (round(p[0]), round(p[1])), 1, _BLUE, -1)
    cv2.putText(canvas, text, (10, 27), _FONT, 0.6, _BLACK, 1, cv2.LINE_AA)
    return canvas


def per_view_plot(result: CalibrationResult) -> np.ndarray:
    """BGR bar chart of each used view's RMS error."""
    errors = np.asarray(result.per_view_rms_px, dtype=np.float64)
    n = max(len(errors), 1)
    width, height, left, top, bottom = 960, 360, 70, 40, 50
    bar = max(2, (width - left - 20) // n)
    canvas = np.full((height, left + bar * n + 30, 3), 255, np.uint8)
    y_max = max(float(errors.max()) if len(errors) else 1.0, 1e-3) * 1.15
    plot_h = height - top - bottom

    def y_of(v: float) -> int:
        return round(top + plot_h * (1.0 - v / y_max))

    for k in range(6):  # y axis ticks
        v = y_max * k / 5
        y = y_of(v)
        cv2.line(canvas, (left - 5, y), (left + bar * n, y), (230, 230, 230), 1)
        cv2.putText(canvas, f"{v:.3f}", (5, y + 4), _FONT, 0.4, _BLACK, 1, cv2.LINE_AA)
    for i, e in enumerate(errors):
        x0 = left + i * bar + 1
        cv2.rectangle(canvas, (x0, y_of(float(e))), (x0 + bar - 2, y_of(0.0)), _BLUE, -1)
        if n <= 40 or i % max(1, n // 40) == 0:
            cv2.putText(canvas, str(result.views_used[i]), (x0, height - bottom + 15), _FONT,
                        0.35, _BLACK, 1, cv2.LINE_AA)
    med = float(np.median(errors)) if len(errors) else 0.0
    cv2.line(canvas, (left, y_of(med)), (left + bar * n, y_of(med)), _RED, 1)
    cv2.line(canvas, (left, top), (left, y_of(0.0)), _BLACK, 1)
    cv2.line(canvas, (left, y_of(0.0)), (left + bar * n, y_of(0.0)), _BLACK, 1)
    cv2.putText(canvas, f"RMS reprojection error per view, px (red: median {med:.3f} px)",
                (10, 25), _FONT, 0.6, _BLACK, 1, cv2.LINE_AA)
    cv2.putText(canvas, "view (position in the input)", (left, height - 12), _FONT, 0.45,
                _BLACK, 1, cv2.LINE_AA)
    return canvas


def write_plots(directory: Path, result: CalibrationResult) -> list[Path]:
    """Write residuals.png, coverage.png and per_view_error.png into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for name, image in (("residuals.png", residual_plot(result)),
                        ("coverage.png", coverage_plot(result)),
                        ("per_view_error.png", per_view_plot(result))):
        out.append(_write(directory / name, image))
    return out


def write_detection_plots(directory: Path, image_size: tuple[int, int],
                          points_px: np.ndarray, views: int) -> list[Path]:
    """The plot a set without a calibration still has: coverage.png of the points detected
    (``points_px`` (P, 2) pixels, from ``views`` images)."""
    directory.mkdir(parents=True, exist_ok=True)
    text = f"{len(points_px)} points detected in {views} images (no calibration)"
    return [_write(directory / "coverage.png", points_plot(image_size, points_px, text))]


def _write(path: Path, image: np.ndarray) -> Path:
    if not cv2.imwrite(str(path), image):
        raise ArtcalError(f"cannot write {path}")
    return path
