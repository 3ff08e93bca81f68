"""What the benchmark plots, drawn with OpenCV, share: a dashed line (OpenCV draws only
solid ones)."""

from __future__ import annotations

import math

import cv2
import numpy as np

__all__ = ["dashed_line"]


def dashed_line(canvas: np.ndarray, a: tuple[int, int], b: tuple[int, int],
                colour: tuple[int, int, int], dash: float = 9.0, gap: float = 6.0) -> None:
    """Draw a dashed line from ``a`` to ``b`` (pixels) on ``canvas`` (BGR, in place), 2 px
    wide, dashes ``dash`` and gaps ``gap`` pixels long."""
    length = math.hypot(b[0] - a[0], b[1] - a[1])
    if length == 0:
        return
    ux, uy = (b[0] - a[0]) / length, (b[1] - a[1]) / length
    s = 0.0
    while s < length:
        e = min(s + dash, length)
        cv2.line(canvas, (round(a[0] + ux * s), round(a[1] + uy * s)),
                 (round(a[0] + ux * e), round(a[1] + uy * e)), colour, 2, cv2.LINE_AA)
        s = e + gap
