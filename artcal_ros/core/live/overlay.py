"""Pictures for a person at the camera: detections over the frame, and the coverage heat map."""

from __future__ import annotations

import functools

import cv2
import numpy as np

from artcal_ros.core.detections import Detections
from artcal_ros.core.live.coverage import Readiness
from artcal_ros.core.live.guidance import MATCH_THRESHOLD, NextPose

_GREEN = (0, 220, 0)
_RED = (0, 0, 230)
_YELLOW = (0, 230, 230)
_ORANGE = (0, 150, 255)


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
    img = np.asarray(image)
    h, w = img.shape[:2]
    zoom = 1.0
    if max_width is not None and w > max_width:
        # shrunk as it comes (grey, 16-bit), before the colour copy is made
        zoom = max_width / w
        size = (int(max_width), max(1, round(h * zoom)))
        img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
    out = to_bgr8(img)
    h, w = out.shape[:2]
    rows, cols = counts.shape
    # Tint covered cells green: a person sees at a glance where the board has not been.
    # (A quarter of the green added to the covered cells' green channel, in place.)
    covered = np.zeros((h, w), np.uint8)
    for r, c in zip(*np.nonzero(counts > 0), strict=True):
        covered[r * h // rows:(r + 1) * h // rows, c * w // cols:(c + 1) * w // cols] = 1
    green = np.ascontiguousarray(out[:, :, 1])
    cv2.add(green, np.full_like(green, _GREEN[1] // 4), dst=green, mask=covered)
    out[:, :, 1] = green
    scale = max(0.4, min(w, h) / 900.0)
    thick = max(1, round(scale * 2))
    if dets is not None and len(dets):
        # pixel centres: (0, 0) is the centre of the top-left pixel at either scale
        quads = np.round((dets.corners_px + 0.5) * zoom - 0.5).astype(np.int32)
        cv2.polylines(out, list(quads), True, _GREEN, thick, cv2.LINE_AA)
        first = quads[:, 0].tolist()
        centers = np.round((dets.centers_px + 0.5) * zoom - 0.5).astype(int).tolist()
        # an id is drawn where it fits inside its marker (smaller ones are unreadable)
        side = np.linalg.norm(quads[:, 1] - quads[:, 0], axis=1)
        label_px = 18.0 * scale
        for k, marker_id in enumerate(dets.ids.tolist()):
            # A red dot on each marker's first (top-left on the board) corner shows orientation.
            cv2.circle(out, (first[k][0], first[k][1]), thick + 1, _RED, -1)
            if side[k] >= label_px * len(str(marker_id)) * 0.6:
                cv2.putText(out, str(marker_id), (centers[k][0] - 8, centers[k][1] + 4),
                            cv2.FONT_HERSHEY_SIMPLEX, 0.8 * scale, _YELLOW, thick,
                            cv2.LINE_8)
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
    rows_px, cols_px, colour, alpha = _text_block(tuple(lines), readiness.ready, scale, thick, w)
    inside = rows_px < h
    r, c, a = rows_px[inside], cols_px[inside], alpha[inside, None]
    out[r, c] = (out[r, c] * (1.0 - a) + colour[inside] * a).astype(np.uint8)
    return out


def draw_next_pose(overlay: np.ndarray, suggestion: NextPose, *, zoom: float = 1.0,
                   match: float = 0.0) -> None:
    """Draw where the board should go next, in place: its outline, orange until the live
    board matches it (``match`` >= :data:`MATCH_THRESHOLD`, see ``pose_match``), then green.

    Args:
        overlay: (H', W', 3) uint8 BGR, the overlay as :func:`render_overlay` made it.
        suggestion: from ``next_pose`` (outline in full-size image pixels).
        zoom: the overlay's scale against the camera image (W' / W).
        match: how well the live board matches the suggestion, [0, 1].
    """
    if len(suggestion.outline_px) < 3:
        return
    h, w = overlay.shape[:2]
    thick = max(2, round(max(0.4, min(w, h) / 900.0) * 3))
    # pixel centres: (0, 0) is the centre of the top-left pixel at either scale
    poly = np.round((suggestion.outline_px + 0.5) * zoom - 0.5).astype(np.int32)
    colour = _GREEN if match >= MATCH_THRESHOLD else _ORANGE
    cv2.polylines(overlay, [poly.reshape(-1, 1, 2)], True, colour, thick, cv2.LINE_AA)


@functools.lru_cache(maxsize=16)
def _text_block(lines: tuple[str, ...], ready: bool, scale: float, thick: int, width: int
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The status lines drawn once (outlined, anti-aliased), as the pixels they cover:
    rows (P,), columns (P,), colours (P, 3) float and opacities (P,) float. The text
    changes a few times a minute, the frames 30 times a second."""
    step = int(28 * scale) + 2
    hh = int(24 * scale) + 4 + step * len(lines)
    picture = np.zeros((hh, width, 3), np.uint8)
    ink = np.zeros((hh, width), np.uint8)
    y = int(24 * scale) + 4
    colour = _GREEN if ready else _YELLOW
    for line in lines:
        for img, col in ((picture, (0, 0, 0)), (ink, 255)):
            cv2.putText(img, line, (8, y), cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale, col,
                        thick + 2, cv2.LINE_AA)
        cv2.putText(picture, line, (8, y), cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale, colour,
                    thick, cv2.LINE_AA)
        cv2.putText(ink, line, (8, y), cv2.FONT_HERSHEY_SIMPLEX, 0.7 * scale, 255, thick,
                    cv2.LINE_AA)
        y += step
    rows_px, cols_px = np.nonzero(ink)
    return (rows_px, cols_px, picture[rows_px, cols_px].astype(np.float64),
            ink[rows_px, cols_px] / 255.0)


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
