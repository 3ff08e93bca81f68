"""The artcal_ros exception hierarchy.

Every error a user can cause (bad parameters, unreadable images, broken bags,
views that cannot support a solve) is one of these, with a message that says
what was wrong and what to do. The CLI turns them into one line and an exit
status; the node into a logged warning or a service answer.
"""

from __future__ import annotations


class ArtcalError(Exception):
    """Base class of every error artcal_ros raises on purpose."""


class ParameterError(ArtcalError):
    """A parameter has a bad value; the message names the parameter."""


class BoardError(ParameterError):
    """The board description is invalid (size, ids, dictionary, polarity)."""


class ImageFormatError(ArtcalError):
    """An image or sensor_msgs/Image message cannot be interpreted.

    ``cause``, when given, is the kind of fault broken frames are counted under (see
    :func:`artcal_ros.core.images.broken_frames.broken_cause`).
    """

    def __init__(self, message: str, *, cause: str | None = None) -> None:
        super().__init__(message)
        self.cause = cause


class BagError(ArtcalError):
    """A rosbag2 / MCAP recording cannot be read or written."""


class DetectionError(ArtcalError):
    """Marker detection was asked something it cannot do."""


class CalibrationError(ArtcalError):
    """The views cannot support a calibration; the message says what is missing."""
