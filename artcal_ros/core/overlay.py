"""Pictures for a person at the camera: detections over the frame, and the coverage heat map."""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.coverage import Readiness
from artcal_ros.core.detections import Detections

_GREEN = (0, 220, 0)
_RED = (0, 0, 230)
_YELLOW = (0, 230, 230)


def to_bgr8(image: np.ndarray) -> np.ndarray:
    """A displayable copy of an image.

    Args:
        image: (H, W) uint8/uint16 or (H, W, 3) uint8 BGR.

    Returns:
        (H, W, 3) uint8 BGR (16-bit images are scaled by their maximum).
    """
    img = np.asarray(image)
    if img.dtype != np.uint8:
        peak = float(img.max()) if img.size else 0.0
        img = (img.astype(np.float64) * (255.0 / peak if peak > 0 else 0.0)).astype(np.uint8)
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    return img.copy()


def render_overlay(image: np.ndarray, dets: Detections | None, counts: np.ndarray,
                   readiness: Readiness, *, kept: bool = False,
                   max_width: int | None = None) -> np.ndarray:
    """The frame with its markers, the coverage so far and what is still missing.

    Args:
        image: (H, W) uint8/uint16 or (H, W, 3) uint8 BGR, the camera frame.
        dets: markers and points found in it (None: detection not run or failed).
        counts: (rows, cols) coverage counts over the image (see ViewCollector.counts).
        readiness: the collection's state, printed as text.
        kept: whether this frame was kept as a calibration view (drawn as a green frame).
        max_width: scale the picture down to at most this width, pixels (the aspect ratio
            kept); None: full size. The frame is shrunk before anything is drawn, so a large
            camera costs little to draw and to send.

    Returns:
        (H', W', 3) uint8 BGR, W' = min(W, max_width).
    """
    out = to_bgr8(image)
    h, w = out.shape[:2]
    zoom = 1.0
    if max_width is not None and w > max_width:
        zoom = max_width / w
        size = (int(max_width), max(1, round(h * zoom)))
        out = cv2.resize(out, size, interpolation=cv2.INTER_AREA)
        h, w = out.shape[:2]
    rows, cols = counts.shape
    # Tint covered cells green: a person sees at a glance where the board has not been.
    tint = np.zeros_like(out)
    for r in range(rows):
        for c in range(cols):
            if counts[r, c] > 0:
                x0, x1 = c * w // cols, (c + 1) * w // cols
                y0, y1 = r * h // rows, (r + 1) * h // rows
                tint[y0:y1, x0:x1] = _GREEN
    out = cv2.addWeighted(out, 1.0, tint, 0.25, 0.0)
    scale = max(0.4, min(w, h) / 900.0)
    thick = max(1, round(scale * 2))
    if dets is not None and len(dets):
        # pixel centres: (0, 0) is the centre of the top-left pixel at either scale
        quads = np.round((dets.corners_px + 0.5) * zoom - 0.5).astype(np.int32)
        cv2.polylines(out, list(quads), True, _GREEN, thick, cv2.LINE_AA)
        for k, marker_id in enumerate(dets.ids):
            # A red dot on each marker's first (top-left on the board) corner shows orientation.
            cv2.circle(out, (int(quads[k, 0, 0]), int(quads[k, 0, 1])), thick + 1, _RED, -1)
            center = (dets.centers_px[k] + 0.5) * zoom - 0.5
            cv2.putText(out, str(int(marker_id)), (int(center[0]) - 8, int(center[1]) + 4),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.8 * scale, _YELLOW, thick, cv2.LINE_AA)
    if dets is not None and len(dets.point_ids):
        pts = np.round((dets.points_px + 0.5) * zoom - 0.5).astype(np.int32)
        for p in pts:
            cv2.circle(out, (int(p[0]), int(p[1])), thick + 2, _RED, thick, cv2.LINE_AA)
    if kept:
        cv2.rectangle(out, (0, 0), (w - 1, h - 1), _GREEN, 3 * thick)
    n = 0 if dets is None else len(dets)
    found = f"markers {n}"
    if dets is not None and len(dets.point_ids):
        found = f"points {len(dets.point_ids)}" + (f"  markers {n}" if n else "")
    lines = [f"{found}  views {readiness.views}/{readiness.views_needed}  "
             f"coverage {readiness.coverage:.0%}"]
    lines += ["ready to calibrate"] if readiness.ready else \
        [f"missing: {item}" for item in readiness.missing]
    y = int(24 * scale) + 4
    for line in lines:
        colour = _GREEN if readiness.ready else _YELLOW
        cv2.putText(out, line, (8, y), cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale, (0, 0, 0),
                    thick + 2, cv2.LINE_AA)
        cv2.putText(out, line, (8, y), cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale, colour, thick,
                    cv2.LINE_AA)
        y += int(28 * scale) + 2
    return out


def render_heat_map(counts: np.ndarray, image_size: tuple[int, int] | None, *,
                    width: int = 320) -> np.ndarray:
    """The coverage counts as a colour heat map with the image's aspect ratio.

    Args:
        counts: (rows, cols) views per grid cell.
        image_size: (width, height) of the camera image, pixels (None: the grid's aspect).
        width: width of the picture, pixels.

    Returns:
        (H, width, 3) uint8 BGR; empty cells black, then blue (few views) to red (many).
    """
    rows, cols = counts.shape
    iw, ih = image_size if image_size is not None else (cols, rows)
    height = max(1, round(width * ih / iw))
    peak = int(counts.max()) if counts.size else 0
    level = np.zeros(counts.shape, np.uint8)
    if peak > 0:
        level = (55 + 200 * counts / peak).astype(np.uint8)
    colour = cv2.applyColorMap(level, cv2.COLORMAP_JET)
    colour[counts == 0] = 0
    return cv2.resize(colour, (width, height), interpolation=cv2.INTER_NEAREST)
