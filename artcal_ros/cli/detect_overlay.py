"""The pictures of ``artcal detect --overlay``: what was found, drawn over each image.

Marker ids are written on a dark plate at their markers' centres and point ids beside their
points, so on a ChArUco board, where every marker's first corner lies next to a board point,
the two kinds of label stay apart; a legend in the top-left corner names the colours.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.detections import Detections

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_OUTLINE = (0, 200, 0)
_CORNER = (0, 0, 255)
_CENTRE = (255, 80, 0)
_MARKER_ID = (0, 120, 255)
_POINT = (255, 0, 255)
LEGEND = (("marker outline", _OUTLINE), ("marker corners", _CORNER),
          ("marker centre", _CENTRE), ("marker id", _MARKER_ID), ("board point, id", _POINT))


@dataclass(frozen=True)
class Label:
    """One id written on the picture: its text, kind and box (pixels, x0 <= x < x1)."""

    text: str
    kind: str  # "marker" or "point"
    x0: int
    y0: int
    x1: int
    y1: int

    @property
    def origin(self) -> tuple[int, int]:
        """Where cv2.putText starts the text (the baseline's left end)."""
        return self.x0, self.y1

    def overlaps(self, other: Label) -> bool:
        """Whether the two boxes share a pixel."""
        return (self.x0 < other.x1 and other.x0 < self.x1
                and self.y0 < other.y1 and other.y0 < self.y1)


def _thickness(shape: tuple[int, ...]) -> int:
    return max(1, round(min(shape[:2]) / 480))


def labels(dets: Detections, thick: int) -> list[Label]:
    """The id labels of ``dets``: marker ids centred on their markers, point ids to the lower
    right of their points, at the sizes :func:`draw_detections` writes them."""
    out = []
    for marker_id, center in zip(dets.ids, dets.centers_px, strict=True):
        text = str(int(marker_id))
        (w, h), _ = cv2.getTextSize(text, _FONT, 0.35 * thick, thick)
        x0, y1 = int(np.round(center[0] - w / 2)), int(np.round(center[1] + h / 2))
        out.append(Label(text, "marker", x0, y1 - h, x0 + w, y1))
    for point_id, xy in zip(dets.point_ids, dets.points_px, strict=True):
        text = str(int(point_id))
        (w, h), _ = cv2.getTextSize(text, _FONT, 0.3 * thick, thick)
        x0, y1 = int(xy[0]) + 4 * thick, int(xy[1]) + 4 * thick + h
        out.append(Label(text, "point", x0, y1 - h, x0 + w, y1))
    return out


def _legend(out: np.ndarray, thick: int) -> None:
    scale = 0.4 * thick
    step = int(16 * thick)
    width = max(cv2.getTextSize(name, _FONT, scale, thick)[0][0] for name, _ in LEGEND)
    cv2.rectangle(out, (0, 0), (width + 12 * thick, step * len(LEGEND) + 6 * thick),
                  (40, 40, 40), -1)
    for k, (name, colour) in enumerate(LEGEND):
        cv2.putText(out, name, (6 * thick, step * (k + 1)), _FONT, scale, colour, thick,
                    cv2.LINE_AA)


def draw_detections(image: np.ndarray, dets: Detections) -> np.ndarray:
    """(H, W, 3) BGR uint8: ``image`` with quads (green), corners (red), centres (blue),
    marker ids (orange), board points and their ids (magenta), and a legend.

    Points are drawn with 1/16-pixel precision at their sub-pixel positions.
    """
    img = image
    if img.dtype == np.uint16:
        img = (img / 257.0).astype(np.uint8)
    out = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img.copy()
    shift = 4
    scale = float(1 << shift)
    thick = _thickness(out.shape)
    for quad, center in zip(dets.corners_px, dets.centers_px, strict=True):
        pts = np.round(quad * scale).astype(np.int32)
        cv2.polylines(out, [pts], True, _OUTLINE, thick, cv2.LINE_AA, shift)
        for p in pts:
            cv2.circle(out, (int(p[0]), int(p[1])), int(2 * scale), _CORNER, thick,
                       cv2.LINE_AA, shift)
        c = np.round(center * scale).astype(np.int32)
        cv2.drawMarker(out, (int(c[0] >> shift), int(c[1] >> shift)), _CENTRE,
                       cv2.MARKER_CROSS, 6 * thick, thick)
    for xy in dets.points_px:
        p = np.round(xy * scale).astype(np.int32)
        cv2.circle(out, (int(p[0]), int(p[1])), int(3 * scale), _POINT, thick, cv2.LINE_AA,
                   shift)
    for label in labels(dets, thick):
        size = 0.35 * thick if label.kind == "marker" else 0.3 * thick
        colour = _MARKER_ID if label.kind == "marker" else _POINT
        if label.kind == "marker":  # on the marker's own black and white bits: a dark plate
            cv2.rectangle(out, (label.x0 - 1, label.y0 - 2), (label.x1, label.y1 + 2),
                          (40, 40, 40), -1)
        cv2.putText(out, label.text, label.origin, _FONT, size, colour, thick, cv2.LINE_AA)
    _legend(out, thick)
    return out
