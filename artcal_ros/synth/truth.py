"""Ground truth of rendered frames: the ``truth.json`` file and its reader.

Format::

    {"camera": {"model", "K": 3x3, "dist": [...], "width", "height"},
     "board": {"board.type", "board.dictionary", "board.cols", ...},
     "photometry": {...}, "seed": int | null,
     "frames": [{"file": "frame_0000.png" | "stamp_ns": int,
                 "rvec": [3], "tvec": [3],             # T_cam_board, metres
                 "markers": [{"id", "corners": [[x, y] x4], "center": [x, y],
                              "inside": bool, "side_px": float}],
                 "points": [{"id", "xy": [x, y], "inside": bool}]}]}   # point boards only

Image points are pixels (OpenCV convention), rounded to 1e-7 px. Markers behind
the camera are left out; ``inside`` is False for markers not wholly in the image.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError
from artcal_ros.core.files import write_text_atomic
from artcal_ros.synth.camera import Camera

_DECIMALS = 7


@dataclass(frozen=True)
class FrameTruth:
    """The exact truth of one frame's markers and points (a render's, or a ``truth.json``
    frame's).

    Attributes:
        rvec, tvec: (3,) the pose T_cam_board (Rodrigues vector; metres).
        ids: (N,) int64 markers (a render: every marker of the board; a ``truth.json``
            frame: those in front of the camera).
        corners_px: (N, 4, 2) float64 true image corners TL TR BR BL, pixels (NaN behind
            the camera).
        centers_px: (N, 2) float64 true image of each marker's centre, pixels.
        inside: (N,) bool, the marker's 4 corners are in front of the camera and in the image.
        side_px: (N,) float64 shortest side of each marker's image, pixels (NaN: unknown).
        point_ids: (M,) int64 board points (saddle points; empty on a marker grid).
        points_px: (M, 2) float64 the true image of each point, pixels (NaN behind the camera).
        points_inside: (M,) bool, the point is in front of the camera and in the image.
    """

    rvec: np.ndarray
    tvec: np.ndarray
    ids: np.ndarray
    corners_px: np.ndarray
    centers_px: np.ndarray
    inside: np.ndarray
    side_px: np.ndarray
    point_ids: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    points_px: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    points_inside: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))

    def perfect_detections(self, image_size: tuple[int, int], *, source: str,
                           min_side_px: float = 0.0) -> Detections:
        """The markers wholly inside the image (and the points in it) as perfect
        :class:`Detections`, optionally only markers whose side is at least ``min_side_px``.

        A marker of unknown side (NaN: a ``truth.json`` written without ``side_px``) is
        kept: the size filter drops only markers known to be smaller.

        Args:
            image_size: (width, height), pixels.
            source: the Detections' source name.
            min_side_px: shortest marker side kept, pixels.
        """
        keep = self.inside & ~(self.side_px < min_side_px)
        pk = self.points_inside
        return Detections(self.ids[keep], self.corners_px[keep], self.centers_px[keep],
                          image_size, source=source, point_ids=self.point_ids[pk],
                          points_px=self.points_px[pk])


@dataclass(frozen=True, kw_only=True)
class TruthFrame(FrameTruth):
    """The truth of one frame of a ``truth.json`` (fields of :class:`FrameTruth`).

    Attributes:
        file: image file name (PNG output) or None; stamp_ns: bag time stamp or None.
    """

    file: str | None
    stamp_ns: int | None

    def true_detections(self, image_size: tuple[int, int], *,
                        min_side_px: float = 0.0) -> Detections:
        """The markers wholly inside the image (and points in it) as perfect
        :class:`Detections`, optionally only markers whose side is >= ``min_side_px``."""
        return self.perfect_detections(image_size, min_side_px=min_side_px,
                                       source=self.file or f"stamp {self.stamp_ns}")


@dataclass(frozen=True)
class Truth:
    """A whole ``truth.json``: the camera, the board and every frame."""

    camera: Camera
    board: Board
    frames: list[TruthFrame]
    photometry: dict[str, Any]
    seed: int | None

    def by_file(self, name: str) -> TruthFrame:
        """The frame of image file ``name`` (base name); ArtcalError if absent."""
        base = os.path.basename(name)
        for f in self.frames:
            if f.file == base:
                return f
        raise ArtcalError(f"truth has no frame for image {base!r}")

    def by_stamp(self, stamp_ns: int) -> TruthFrame:
        """The frame with bag time stamp ``stamp_ns``; ArtcalError if absent."""
        for f in self.frames:
            if f.stamp_ns == stamp_ns:
                return f
        raise ArtcalError(f"truth has no frame with stamp {stamp_ns} ns")


def board_params(board: Board) -> dict[str, Any]:
    """The ``board.*`` parameters that rebuild ``board`` with :meth:`Board.from_params`."""
    return board.to_params()


def frame_record(*, rvec: np.ndarray, tvec: np.ndarray, ids: np.ndarray,
                 corners_px: np.ndarray, centers_px: np.ndarray, inside: np.ndarray,
                 side_px: np.ndarray, file: str | None = None,
                 stamp_ns: int | None = None, point_ids: np.ndarray | None = None,
                 points_px: np.ndarray | None = None,
                 points_inside: np.ndarray | None = None) -> dict[str, Any]:
    """One frame's JSON record (markers behind the camera are left out)."""
    rec: dict[str, Any] = {"file": file} if file is not None else {"stamp_ns": int(stamp_ns or 0)}
    rec["rvec"] = [float(v) for v in np.ravel(rvec)]
    rec["tvec"] = [float(v) for v in np.ravel(tvec)]
    markers = []
    for k in range(len(ids)):
        if not (np.all(np.isfinite(corners_px[k])) and np.all(np.isfinite(centers_px[k]))):
            continue
        markers.append({
            "id": int(ids[k]),
            "corners": np.round(corners_px[k], _DECIMALS).tolist(),
            "center": np.round(centers_px[k], _DECIMALS).tolist(),
            "inside": bool(inside[k]),
            "side_px": round(float(side_px[k]), 4)})
    rec["markers"] = markers
    if point_ids is not None and points_px is not None and len(point_ids):
        inside_p = (np.ones(len(point_ids), bool) if points_inside is None
                    else np.asarray(points_inside))
        rec["points"] = [{"id": int(i), "xy": np.round(p, _DECIMALS).tolist(),
                          "inside": bool(f)}
                         for i, p, f in zip(point_ids, points_px, inside_p, strict=True)
                         if np.all(np.isfinite(p))]
    return rec


def write_truth(path: str | Path, camera: Camera, board: Board,
                frames: Sequence[dict[str, Any]], *, photometry: dict[str, Any] | None = None,
                seed: int | None = None) -> None:
    """Write ``truth.json`` atomically (frames: records from :func:`frame_record`)."""
    write_json_atomic(path, {"camera": camera.to_dict(), "board": board_params(board),
                             "photometry": photometry or {}, "seed": seed,
                             "frames": list(frames)})


def write_json_atomic(path: str | Path, doc: Any) -> None:
    """Write ``doc`` as compact JSON to ``path`` atomically (a reader never sees a part)."""
    write_text_atomic(path, json.dumps(doc, separators=(",", ":")) + "\n")


def truth_frame(rec: dict[str, Any]) -> TruthFrame:
    """One frame record of a truth file (see :func:`frame_record`) as a :class:`TruthFrame`.

    Raises:
        ValueError, KeyError, TypeError, IndexError: the record is malformed.
    """
    ms = rec["markers"]
    ps = rec.get("points", [])
    return TruthFrame(
        file=rec.get("file"),
        stamp_ns=int(rec["stamp_ns"]) if "stamp_ns" in rec else None,
        rvec=np.array(rec["rvec"], dtype=np.float64),
        tvec=np.array(rec["tvec"], dtype=np.float64),
        ids=np.array([m["id"] for m in ms], dtype=np.int64),
        corners_px=np.array([m["corners"] for m in ms], dtype=np.float64).reshape(-1, 4, 2),
        centers_px=np.array([m["center"] for m in ms], dtype=np.float64).reshape(-1, 2),
        inside=np.array([m["inside"] for m in ms], dtype=bool),
        side_px=np.array([m.get("side_px", np.nan) for m in ms], dtype=np.float64),
        point_ids=np.array([p["id"] for p in ps], dtype=np.int64),
        points_px=np.array([p["xy"] for p in ps], dtype=np.float64).reshape(-1, 2),
        points_inside=np.array([p["inside"] for p in ps], dtype=bool))


def load_truth(path: str | Path) -> Truth:
    """Read a ``truth.json`` written by ``artcal synth`` (ArtcalError if it is not one)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
        camera = Camera.from_dict(doc["camera"])
        board = Board.from_params(doc["board"])
        frames = [truth_frame(rec) for rec in doc["frames"]]
    except OSError as e:
        raise ArtcalError(f"cannot read truth file {path}: {e.strerror}") from e
    except (ValueError, KeyError, TypeError, IndexError) as e:
        raise ArtcalError(f"{path} is not a truth.json written by 'artcal synth' "
                          f"({type(e).__name__}: {e})") from e
    return Truth(camera=camera, board=board, frames=frames,
                 photometry=dict(doc.get("photometry") or {}), seed=doc.get("seed"))
