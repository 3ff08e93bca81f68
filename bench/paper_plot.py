"""Line charts for :mod:`bench.paper`, drawn with OpenCV (no plotting library needed)."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from bench.drawing import dashed_line

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_BLACK = (0, 0, 0)
# BGR, one per camera / method
COLOURS = ((190, 100, 20), (40, 40, 210), (60, 150, 40), (0, 140, 230), (150, 60, 150),
           (120, 120, 120))


@dataclass(frozen=True)
class Series:
    """One curve: its label, (x, y) points (NaN y skipped), colour (BGR), dashed or solid."""

    label: str
    x: tuple[float, ...]
    y: tuple[float, ...]
    colour: tuple[int, int, int]
    dashed: bool = False


def _ticks(lo: float, hi: float) -> list[float]:
    """1, 2, 5 per decade between lo and hi."""
    out = []
    for d in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1):
        out += [m * 10.0 ** d for m in (1, 2, 5) if lo <= m * 10.0 ** d <= hi]
    return out


def line_chart(series: list[Series], *, title: str, x_label: str, y_label: str,
               log_x: bool = False, size: tuple[int, int] = (1000, 560)) -> np.ndarray:
    """BGR image of ``series`` on a log y axis, legend on the right."""
    width, height = size
    left, right, top, bottom = 80, 260, 50, 60
    img = np.full((height, width, 3), 255, np.uint8)
    xs = [x for s in series for x in s.x]
    ys = [y for s in series for y in s.y if math.isfinite(y) and y > 0]
    if not xs or not ys:
        cv2.putText(img, f"{title}: no data", (left, top), _FONT, 0.6, _BLACK, 1, cv2.LINE_AA)
        return img
    y_lo = 10.0 ** math.floor(math.log10(min(ys)))
    y_hi = 10.0 ** math.ceil(math.log10(max(ys)))
    fx = math.log10 if log_x else float
    x_lo, x_hi = fx(min(xs)), fx(max(xs))
    x_hi = x_hi if x_hi > x_lo else x_lo + 1.0
    pw, ph = width - left - right, height - top - bottom

    def xy(x: float, y: float) -> tuple[int, int]:
        u = (fx(x) - x_lo) / (x_hi - x_lo)
        v = (math.log10(y) - math.log10(y_lo)) / (math.log10(y_hi) - math.log10(y_lo))
        return round(left + u * pw), round(top + (1.0 - v) * ph)

    for v in _ticks(y_lo, y_hi):
        _, y = xy(min(xs), v)
        cv2.line(img, (left, y), (left + pw, y), (225, 225, 225), 1)
        cv2.putText(img, f"{v:g}", (left - 60, y + 5), _FONT, 0.45, _BLACK, 1, cv2.LINE_AA)
    for x in sorted(set(xs)):
        px, _ = xy(x, y_lo)
        cv2.line(img, (px, top), (px, top + ph), (240, 240, 240), 1)
        label = f"{x:.0f}" if x >= 10 else f"{x:g}"
        cv2.putText(img, label, (px - 8, top + ph + 20), _FONT, 0.4, _BLACK, 1, cv2.LINE_AA)
    cv2.rectangle(img, (left, top), (left + pw, top + ph), _BLACK, 1)
    cv2.putText(img, title, (left, top - 18), _FONT, 0.6, _BLACK, 1, cv2.LINE_AA)
    cv2.putText(img, x_label, (left + pw // 2 - 60, height - 15), _FONT, 0.5, _BLACK, 1,
                cv2.LINE_AA)
    cv2.putText(img, y_label, (8, top - 18), _FONT, 0.45, _BLACK, 1, cv2.LINE_AA)
    legend_y = top + 10
    for s in series:
        pts = [xy(x, y) for x, y in zip(s.x, s.y, strict=True) if math.isfinite(y) and y > 0]
        for a, b in itertools.pairwise(pts):
            if s.dashed:
                dashed_line(img, a, b, s.colour, dash=7.0, gap=5.0)
            else:
                cv2.line(img, a, b, s.colour, 2, cv2.LINE_AA)
        for q in pts:
            cv2.circle(img, q, 3, s.colour, -1, cv2.LINE_AA)
        lx = left + pw + 15
        if s.dashed:
            dashed_line(img, (lx, legend_y), (lx + 36, legend_y), s.colour, dash=7.0,
                        gap=5.0)
        else:
            cv2.line(img, (lx, legend_y), (lx + 36, legend_y), s.colour, 2, cv2.LINE_AA)
        cv2.putText(img, s.label, (lx + 44, legend_y + 5), _FONT, 0.42, _BLACK, 1, cv2.LINE_AA)
        legend_y += 22
    return img


def stack(images: list[np.ndarray]) -> np.ndarray:
    """Charts of the same width one below the other."""
    return np.vstack(images)
