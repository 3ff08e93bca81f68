"""A rig's frames for ``artcal calibrate --camera ...``: image folders paired by sorted order,
or a bag's topics paired by stamp, detected camera by camera.

Each camera has its own :class:`~artcal_ros.core.detect.Detector` (its tone curve and lens
estimate are that camera's); a frame a camera could not read (a broken file or message, an
image of another size) is counted in :class:`~artcal_ros.cli.skipped.SkippedFrames` and is
a frame that camera saw nothing in.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from artcal_ros.cli.bag_images import frames_affordable, message_image
from artcal_ros.cli.progress import Progress
from artcal_ros.cli.skipped import (
    SkippedFrames,
    expand_image_paths,
    folder_hint,
    read_image_file,
)
from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, DetectorConfig
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import BagError, ImageFormatError, ParameterError

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")


@dataclass
class RigFrames:
    """The detections of a rig's frames.

    Attributes:
        names: the cameras, in the order given.
        detections: camera -> one entry per rig frame (None: nothing read for it).
        sizes: camera -> (width, height) of its images, pixels.
        topics: camera -> its image topic (a bag), or ``/<camera>/image_raw``.
        detectors: camera -> the detector that read its frames (its tone curve).
        note: how the frames were paired, for the output.
    """

    names: tuple[str, ...]
    detections: dict[str, list[Detections | None]]
    sizes: dict[str, tuple[int, int]]
    topics: dict[str, str]
    detectors: dict[str, Detector] = field(default_factory=dict)
    note: str = ""


class _Reader:
    """Detects each camera's frames with its own detector; tracks its image size."""

    def __init__(self, names: tuple[str, ...], board: Board, params: Mapping[str, Any],
                 skipped: SkippedFrames) -> None:
        config = DetectorConfig.from_params(params)
        self.detectors = {n: Detector(board, config) for n in names}
        self.sizes: dict[str, tuple[int, int]] = {}
        self.skipped = skipped

    def detect(self, name: str, image: np.ndarray, source: str) -> Detections | None:
        h, w = image.shape[:2]
        size = self.sizes.setdefault(name, (w, h))
        if size != (w, h):
            self.skipped.add(f"{name}: {w}x{h} image, not its first frame's "
                             f"{size[0]}x{size[1]}")
            return None
        return self.detectors[name].detect(image, source=source)


def _sizes(reader: _Reader, names: tuple[str, ...]) -> dict[str, tuple[int, int]]:
    missing = [n for n in names if n not in reader.sizes]
    if missing:
        raise ImageFormatError(f"no usable frame of camera {', '.join(missing)}: "
                               f"{reader.skipped.summary()}")
    return dict(reader.sizes)


def folder_frames(globs: Mapping[str, str], board: Board, params: Mapping[str, Any], *,
                  quiet: bool, skipped: SkippedFrames) -> RigFrames:
    """Each camera's image files (``NAME=GLOB``), paired by sorted order, detected.

    Raises:
        ParameterError: a pattern matches nothing, or the cameras have different numbers of
            images (both counts named).
    """
    names = tuple(globs)
    for n, g in globs.items():
        if os.path.isdir(g):
            raise ParameterError(f"--camera {n}={g}: a directory; {folder_hint(g)} "
                                 "(quoted, so the files are paired here in sorted order)")
    files = {n: expand_image_paths([g]) for n, g in globs.items()}
    counts = {n: len(f) for n, f in files.items()}
    if len(set(counts.values())) > 1:
        said = ", ".join(f"{n} {c} ({globs[n]})" for n, c in counts.items())
        raise ParameterError(f"the cameras have different numbers of images: {said}; a rig's "
                             "image files are paired by sorted order, so every camera needs "
                             "one per frame")
    reader = _Reader(names, board, params, skipped)
    n_frames = counts[names[0]]
    dets: dict[str, list[Detections | None]] = {n: [] for n in names}
    bar: Progress[Any] = Progress(total=n_frames * len(names), label="detect rig",
                                  enabled=not quiet)
    for i in range(n_frames):
        for n in names:
            path = files[n][i]
            try:
                image = read_image_file(path)
            except ImageFormatError as e:
                skipped.add(e)
                dets[n].append(None)
            else:
                dets[n].append(reader.detect(n, image, path))
            bar.update()
    bar.close()
    return RigFrames(names, dets, _sizes(reader, names), {n: f"/{n}/image_raw" for n in names},
                     reader.detectors, f"{n_frames} frames paired by sorted file order")


def _check_topics(recorded: Mapping[str, str], topics: Mapping[str, str], bag: str) -> None:
    for name, topic in topics.items():
        if topic not in recorded:
            listed = ", ".join(f"{t} ({kind or 'no type'})"
                               for t, kind in sorted(recorded.items()))
            raise ParameterError(f"--camera {name}={topic}: not in {bag} (topics: "
                                 f"{listed or 'none'})")
        if recorded[topic] not in IMAGE_TYPES:
            raise ParameterError(f"--camera {name}={topic}: is {recorded[topic]}, not an image "
                                 "topic")
    if len(set(topics.values())) != len(topics):
        raise ParameterError("--camera: two cameras name the same topic; give each its own")


def bag_frames(bag: str, topics: Mapping[str, str], board: Board, params: Mapping[str, Any],
               *, max_frames: int, budget_s: float, quiet: bool, skipped: SkippedFrames,
               warn: Callable[[str], None]) -> RigFrames:
    """The bag's messages of each camera's topic, paired by header stamp within the
    ``sync_tolerance`` parameter (:func:`~artcal_ros.core.sync.pair_by_stamp`), detected.

    At most ``max_frames`` rig frames (0: no limit) spread evenly over the recording are
    detected; with a time budget the spacing adapts so reading and detecting take about
    ``budget_s`` seconds (as for one camera).

    Raises:
        ParameterError: a topic is missing or no image topic; no frame pairs.
    """
    from artcal_ros.bag import BagReader
    from artcal_ros.bag.header import header_stamp_ns
    from artcal_ros.core.sync import pair_by_stamp

    names = tuple(topics)
    camera_of = {t: n for n, t in topics.items()}
    tolerance_s = float(params["sync_tolerance"])
    start = time.monotonic()
    with BagReader(bag) as reader:
        _check_topics(reader.topics, topics, bag)
        wanted = list(topics.values())
        stamps: dict[str, list[int]] = {n: [] for n in names}
        for m in reader.messages(wanted, on_damage="stop"):
            stamps[camera_of[m.topic]].append(header_stamp_ns(m))
        groups, unpaired = pair_by_stamp(stamps, tolerance_ns=round(tolerance_s * 1e9))
        left_out = ", ".join(f"{n} {unpaired[n]} of {len(stamps[n])}" for n in names)
        note = (f"{len(groups)} rig frames paired by stamp within {tolerance_s:g} s "
                f"(sync_tolerance); unpaired messages: {left_out}")
        if not groups:
            raise ParameterError(f"{bag}: no messages of {', '.join(wanted)} pair within "
                                 f"sync_tolerance {tolerance_s:g} s (unpaired: {left_out}); "
                                 "raise it with --set sync_tolerance=SECONDS if the cameras "
                                 "are not triggered together")
        frame_of = {(n, k): f for f, g in enumerate(groups) for n, k in g.items()}
        total = len(groups)
        cap = total if max_frames <= 0 else min(max_frames, total)
        rdr = _Reader(names, board, params, skipped)
        slots: dict[int, int] = {}           # rig frame -> position among those detected
        dets: dict[str, list[Detections | None]] = {n: [] for n in names}
        bar: Progress[Any] = Progress(total=cap * len(names), label="detect rig",
                                      enabled=not quiet)
        next_index, count = 0.0, {n: 0 for n in names}
        for m in reader.messages(wanted, on_damage="stop"):
            n = camera_of[m.topic]
            k = count[n]
            count[n] += 1
            f = frame_of.get((n, k))
            if f is None:
                continue
            if f not in slots:   # a frame's first message: take the frame or not
                if f < next_index or len(slots) >= cap:
                    continue
                slots[f] = len(slots)
                for each in names:
                    dets[each].append(None)
                # paced by the frames begun before this one
                left = frames_affordable(cap - len(slots), len(slots) - 1,
                                         time.monotonic() - start, budget_s)
                next_index = (f + max(1.0, (total - f - 1) / left) if left > 0
                              else float(total))
            try:
                image = message_image(m)
            except (BagError, ImageFormatError) as e:
                skipped.add(e)
                continue
            dets[n][slots[f]] = rdr.detect(n, image, f"{m.topic}#{k}@{m.log_time_ns}")
            bar.update()
        bar.close()
        for text in dict.fromkeys(reader.warnings):
            warn(text)
    if len(slots) < total:
        note += f"; {len(slots)} of them detected, spread over the recording"
    return RigFrames(names, dets, _sizes(rdr, names), dict(topics), rdr.detectors, note)
