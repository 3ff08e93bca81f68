"""What ``artcal calibrate`` writes with ``--report DIR``, and the lines that lead its output.

A calibrated set: ``summary.json`` (the result's summary with ``success`` true, its
verdict, where the board was found and the caller's extra keys), ``detections.json`` (the
``artcal detect --json`` records of every image), ``report.pdf`` and its pages as PNGs
(:mod:`artcal_ros.core.calibrate.report`). A refused set still gets
``DIR``: ``summary.json`` with ``success`` false and the ``reason``, the keys of DESIGN.md
that apply without a calibration (``model``, ``points``, ``views_used`` empty,
``warnings``, ``tone_curve``, ``board_check``), ``detections.json`` and the coverage plot of
the points detected (report.pdf, verdict.png, coverage.png).
"""

from __future__ import annotations

import json
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate import CalibrationResult
from artcal_ros.core.calibrate.diagnosis import BoardSearch
from artcal_ros.core.detections import Detections, tag_corner_points
from artcal_ros.core.errors import ArtcalError

SAMPLE_SIZE = 8  # frames kept for the search of what else is in view


class FrameSample:
    """Keeps at most ``size`` frames spread evenly over a stream of unknown length.

    Every ``step``-th frame is kept; when more than ``size`` are held, ``step`` doubles and
    the frames off the new step are let go.
    """

    def __init__(self, size: int = SAMPLE_SIZE) -> None:
        self.size = size
        self.step = 1
        self.count = 0
        self.kept: dict[int, np.ndarray] = {}

    def wrap(self, frames: Iterator[tuple[str, np.ndarray]]
             ) -> Iterator[tuple[str, np.ndarray]]:
        """The same frames, keeping the sample on the way (positions count from 0)."""
        for source, image in frames:
            k = self.count
            self.count += 1
            if k % self.step == 0:
                self.kept[k] = image
                if len(self.kept) > self.size:
                    self.step *= 2
                    self.kept = {i: im for i, im in self.kept.items() if i % self.step == 0}
            yield source, image

    def images(self) -> list[tuple[int, np.ndarray]]:
        """(position in the stream, image) of the frames kept, in order."""
        return sorted(self.kept.items(), key=lambda kv: kv[0])


def arrange_summary(text: str, search: BoardSearch, result: CalibrationResult) -> str:
    """The long summary ``text`` (its first line the verdict) with the board found in under
    half of the images said first; a weak solve's verdict, which states its uncertainty,
    stays first."""
    lines = text.splitlines()
    if search.partial:
        lines.insert(1 if result.weak_reason else 0, search.text())
    return "\n".join(lines)


def _records(dets: list[Detections], board: Board) -> list[dict[str, Any]]:
    out = []
    for d in dets:
        listed = tag_corner_points(d, board) if board.board_type == "aprilgrid" else d
        out.append(listed.to_json(with_points=board.has_points))
    return out


def _write_json(path: Path, data: Any) -> None:
    path.write_text(json.dumps(data, indent=1) + "\n")


def write_report(directory: Path, result: CalibrationResult, dets: list[Detections],
                 board: Board, extra: Mapping[str, Any] | None = None,
                 title: str = "") -> list[Path]:
    """The report (:func:`artcal_ros.core.calibrate.report.write_report`: summary.json with
    ``extra`` keys, report.pdf and its PNGs) and detections.json."""
    from artcal_ros.core.calibrate.report import write_report as write_calibration_report

    keys = dict(extra or {})
    summary_extra = {"frames": len(dets),
                     "sources_used": [dets[i].source for i in result.views_used], **keys}
    written = write_calibration_report(
        directory, result, tone_curve=keys.pop("tone_curve", None),
        board_check=keys.pop("board_check", None), detections=dets, board=board,
        extra=summary_extra, title=title)
    try:
        _write_json(directory / "detections.json", {"images": _records(dets, board)})
    except OSError as e:
        raise ArtcalError(f"cannot write the report into {directory}: {e.strerror}") from None
    return [*written, directory / "detections.json"]


def write_refused_report(directory: Path, reason: str, dets: list[Detections], board: Board,
                         params: Mapping[str, Any], image_size: tuple[int, int],
                         extra: Mapping[str, Any] | None = None) -> list[Path]:
    """The report of a set that gave no calibration: the reason, the detections and the
    coverage of the points detected (see the module docstring)."""
    from artcal_ros.core.calibrate.report import write_refused_report as write_refused

    per_image = []
    points = []
    for d in dets:
        xy = d.points_px if len(d.point_ids) else d.centers_px
        points.append(np.asarray(xy, np.float64).reshape(-1, 2))
        per_image.append({"file": d.source, "markers": len(d.ids), "points": len(d.point_ids)})
    summary: dict[str, Any] = {
        "success": False, "reason": reason, "model": str(params["camera_model"]),
        "points": str(params["points"]), "image_width": int(image_size[0]),
        "image_height": int(image_size[1]), "frames": len(dets), "views_used": [],
        "warnings": [reason], "per_image": per_image}
    summary.update(extra or {})
    all_points = np.concatenate(points) if points else np.zeros((0, 2))
    written = write_refused(directory, reason, image_size, all_points, images=len(dets),
                            summary=summary)
    try:
        _write_json(directory / "detections.json", {"images": _records(dets, board)})
    except OSError as e:
        raise ArtcalError(f"cannot write the report into {directory}: {e.strerror}") from None
    return [*written, directory / "detections.json"]
