"""Frames the ``artcal`` verbs skip (unreadable files, broken messages), counted by cause.

One bad frame among hundreds should not cost a user the calibration: the verbs skip it,
count it, and name the causes once in their summary::

    skipped 2 broken frames: 1 unknown encoding 'yuv_weird'; 1 cannot read image b.png: ...

The image files come from the command line as given; a wildcard the shell left alone
(quoted, or matching nothing) is expanded here, and one that matches nothing is a usage
error naming it, not a broken frame.
"""

from __future__ import annotations

import glob
import os
from collections import Counter
from pathlib import Path

import numpy as np

from artcal_ros.core.errors import ArtcalError, ImageFormatError, ParameterError
from artcal_ros.core.images.broken_frames import BrokenTally, broken_cause

# File name endings OpenCV's imread decodes (lower case), for the hint on a folder.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".pgm", ".ppm", ".pnm",
                  ".webp", ".jp2", ".exr", ".hdr")


class SkippedFrames:
    """Counts skipped frames by cause, in the node's cause table
    (:func:`~artcal_ros.core.images.broken_frames.broken_cause`)."""

    def __init__(self) -> None:
        self._tally = BrokenTally()

    def add(self, error: ArtcalError | str) -> None:
        """Count one skipped frame; ``error`` says why."""
        self._tally.add(broken_cause(error))

    @property
    def count(self) -> int:
        """Frames skipped."""
        return self._tally.total()

    def summary(self) -> str:
        """``skipped 3 broken frames: 2 <cause>; 1 <cause>`` (the most frequent first), or ""
        when none was skipped."""
        counts = self._tally.counts()
        if not counts:
            return ""
        total = sum(counts.values())
        plural = "s" if total != 1 else ""
        by_count = sorted(counts.items(), key=lambda item: -item[1])
        causes = "; ".join(f"{n} {cause}" for cause, n in by_count)
        return f"skipped {total} broken frame{plural}: {causes}"


def read_image_file(path: str) -> np.ndarray:
    """An image file as (H, W) uint8/uint16 or (H, W, 3) BGR uint8/uint16.

    Raises:
        ImageFormatError: naming the file and why it cannot be used (missing, a directory,
            not an image OpenCV decodes, a pixel type other than 8 or 16 bit).
    """
    import cv2

    if os.path.isdir(path):
        raise _file_error(f"cannot read image {path}: it is a directory "
                               f"({folder_hint(path)})")
    if not os.path.isfile(path):
        raise _file_error(f"cannot read image {path}: no such file")
    try:
        image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None:
        raise _file_error(f"cannot read image {path}: not an image OpenCV can decode")
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
    if image.dtype not in (np.uint8, np.uint16) or image.ndim not in (2, 3) or (
            image.ndim == 3 and image.shape[2] not in (1, 3)):
        raise _file_error(f"cannot use image {path}: {image.dtype} pixels of shape "
                               f"{image.shape}; save it as 8- or 16-bit grey or colour")
    return np.asarray(image)


def _file_error(message: str) -> ImageFormatError:
    """An unreadable file's error; its cause names the file as given (a file is one broken
    frame the user must find, and the numbers in its name are part of that name)."""
    return ImageFormatError(message, cause=message.split("; ", 1)[0])


def folder_hint(folder: str) -> str:
    """What to give instead of a folder: its images by their most common ending
    (``give the image files in it, e.g. frames/*.jpg``), or that it holds none."""
    try:
        names = os.listdir(folder)
    except OSError as e:
        return f"and cannot be listed: {e.strerror or e}"
    endings = Counter(Path(n).suffix for n in names
                      if Path(n).suffix.lower() in IMAGE_SUFFIXES
                      and os.path.isfile(os.path.join(folder, n)))
    if not endings:
        return "with no image files in it"
    pattern = ", ".join(str(Path(folder) / f"*{end}") for end, _ in endings.most_common(2))
    return f"give the image files in it, e.g. {pattern}"


def expand_image_paths(paths: list[str]) -> list[str]:
    """The image files named on the command line, with wildcards the shell left alone
    (quoted, or matching nothing) expanded here, each pattern's matches sorted.

    Raises:
        ParameterError: a pattern matches no file (``no file matches frames/*.png``).
    """
    out: list[str] = []
    for path in paths:
        if os.path.exists(path) or not any(c in path for c in "*?["):
            out.append(path)
            continue
        matches = sorted(glob.glob(os.path.expanduser(path)))
        if not matches:
            raise ParameterError(f"no file matches {path}")
        out.extend(matches)
    return out
