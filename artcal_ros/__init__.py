"""artcal_ros: camera calibration from boards of self-identifying 6x6-bit markers.

The Python API::

    from artcal_ros import Board, Detector, calibrate, calibrate_rig, detect, load_params
"""

from __future__ import annotations

from typing import Any

from artcal_ros.core.board import Board
from artcal_ros.core.errors import (
    ArtcalError,
    BagError,
    BoardError,
    CalibrationError,
    ImageFormatError,
    ParameterError,
)
from artcal_ros.core.params import load_params

__all__ = [
    "ArtcalError",
    "BagError",
    "Board",
    "BoardError",
    "CalibrationError",
    "Detector",
    "ImageFormatError",
    "ParameterError",
    "calibrate",
    "calibrate_rig",
    "detect",
    "load_params",
]


def __getattr__(name: str) -> Any:
    # detect and calibrate pull in the heavier modules only when used.
    if name == "detect":
        from artcal_ros.core.detect import detect

        return detect
    if name == "Detector":
        from artcal_ros.core.detect import Detector

        return Detector
    if name == "calibrate":
        from artcal_ros.core.calibrate import calibrate

        return calibrate
    if name == "calibrate_rig":
        from artcal_ros.core.calibrate.rig import calibrate_rig

        return calibrate_rig
    raise AttributeError(name)
