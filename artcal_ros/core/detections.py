"""The result of detecting a board in one image (shared by detection, calibration and I/O)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from artcal_ros.core.board import Board


@dataclass(frozen=True)
class Detections:
    """Markers and points found in one image, in OpenCV pixel coordinates (top-left pixel
    centre = (0, 0)).

    A marker grid has markers only; a chessboard has points only; a ChArUco board has both
    (its markers identify the points, its points are what a solve uses).

    Attributes:
        ids: (N,) int64 marker ids, all on the board.
        corners_px: (N, 4, 2) float64, pixels; corner order TL, TR, BR, BL on the board.
        centers_px: (N, 2) float64, pixels; the image of each marker's centre.
        image_size: (width, height) of the image, pixels.
        corner_sigma_px: (N, 4) float64, estimated 1-sigma error of each corner, pixels
            (NaN where unknown).
        center_sigma_px: (N,) float64, the same for each centre.
        sharpness: a focus measure of the image (larger is sharper; NaN if unknown).
        source: where the image came from (a file name or a bag message), for reports.
        point_ids: (M,) int64 ids of the board's points found (``Board.object_points``).
        points_px: (M, 2) float64, pixels; the image of each point.
        point_sigma_px: (M,) float64, estimated 1-sigma error of each point, pixels.
        edge_shift_px: the edge shift measured in this view and removed from the corners
            (outward from the border positive; NaN when not measured), pixels.
    """

    ids: np.ndarray
    corners_px: np.ndarray
    centers_px: np.ndarray
    image_size: tuple[int, int]
    corner_sigma_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    center_sigma_px: np.ndarray = field(default_factory=lambda: np.zeros((0,)))
    sharpness: float = float("nan")
    source: str = ""
    point_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    points_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point_sigma_px: np.ndarray = field(default_factory=lambda: np.zeros(0))
    edge_shift_px: float = float("nan")

    def __post_init__(self) -> None:
        n = len(self.ids)
        object.__setattr__(self, "ids", np.asarray(self.ids, dtype=np.int64).reshape(n))
        object.__setattr__(self, "corners_px",
                           np.asarray(self.corners_px, dtype=np.float64).reshape(n, 4, 2))
        object.__setattr__(self, "centers_px",
                           np.asarray(self.centers_px, dtype=np.float64).reshape(n, 2))
        if len(self.corner_sigma_px) != n:
            object.__setattr__(self, "corner_sigma_px", np.full((n, 4), np.nan))
        if len(self.center_sigma_px) != n:
            object.__setattr__(self, "center_sigma_px", np.full((n,), np.nan))
        m = len(self.point_ids)
        object.__setattr__(self, "point_ids",
                           np.asarray(self.point_ids, dtype=np.int64).reshape(m))
        object.__setattr__(self, "points_px",
                           np.asarray(self.points_px, dtype=np.float64).reshape(m, 2))
        if len(self.point_sigma_px) != m:
            object.__setattr__(self, "point_sigma_px", np.full((m,), np.nan))

    def __len__(self) -> int:
        return len(self.ids)

    @classmethod
    def empty(cls, image_size: tuple[int, int], source: str = "") -> Detections:
        """No markers."""
        return cls(np.zeros(0, np.int64), np.zeros((0, 4, 2)), np.zeros((0, 2)),
                   image_size, source=source)

    @property
    def n_features(self) -> int:
        """Correspondences found: points where the board has them, else markers."""
        return len(self.point_ids) if len(self.point_ids) else len(self.ids)

    def subset(self, mask: np.ndarray) -> Detections:
        """Only the markers where ``mask`` (bool (N,) or index array) selects (points kept)."""
        return Detections(self.ids[mask], self.corners_px[mask], self.centers_px[mask],
                          self.image_size, self.corner_sigma_px[mask],
                          self.center_sigma_px[mask], self.sharpness, self.source,
                          self.point_ids, self.points_px, self.point_sigma_px,
                          self.edge_shift_px)

    def with_points(self, point_ids: np.ndarray, points_px: np.ndarray,
                    point_sigma_px: np.ndarray | None = None) -> Detections:
        """These markers with the given points (ids (M,), pixels (M, 2), sigmas (M,))."""
        sigma = np.full(len(point_ids), np.nan) if point_sigma_px is None else point_sigma_px
        return replace(self, point_ids=point_ids, points_px=points_px, point_sigma_px=sigma)

    def to_json(self, file: str | None = None, *, with_points: bool = False) -> dict[str, Any]:
        """The ``artcal detect --json`` record of this image (``points`` for point boards)."""
        w, h = self.image_size
        record: dict[str, Any] = {
            "file": self.source if file is None else file,
            "width": int(w),
            "height": int(h),
            "markers": [
                {"id": int(i), "corners": c.tolist(), "center": m.tolist()}
                for i, c, m in zip(self.ids, self.corners_px, self.centers_px, strict=True)
            ],
        }
        if with_points or len(self.point_ids):
            record["points"] = [{"id": int(i), "xy": p.tolist()}
                                for i, p in zip(self.point_ids, self.points_px, strict=True)]
        return record

    @classmethod
    def from_json(cls, record: dict[str, Any]) -> Detections:
        """Read back one image record of the ``artcal detect --json`` format."""
        markers = record.get("markers", [])
        points = record.get("points", [])
        return cls(
            np.array([m["id"] for m in markers], dtype=np.int64),
            np.array([m["corners"] for m in markers], dtype=np.float64).reshape(-1, 4, 2),
            np.array([m["center"] for m in markers], dtype=np.float64).reshape(-1, 2),
            (int(record["width"]), int(record["height"])),
            source=str(record.get("file", "")),
            point_ids=np.array([p["id"] for p in points], dtype=np.int64),
            points_px=np.array([p["xy"] for p in points], dtype=np.float64).reshape(-1, 2),
        )


def tag_corner_points(dets: Detections, board: Board) -> Detections:
    """``dets`` with its markers' corners also listed as the board's points: an aprilgrid's
    tag corners under Kalibr's point ids (ascending), for ``artcal detect --json``."""
    pids = board.marker_point_ids(dets.ids).reshape(-1)
    order = np.argsort(pids, kind="stable")
    return dets.with_points(pids[order], dets.corners_px.reshape(-1, 2)[order],
                            dets.corner_sigma_px.reshape(-1)[order])
