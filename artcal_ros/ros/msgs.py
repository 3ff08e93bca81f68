"""Glue between numpy / core results and ROS messages (no algorithms here)."""

from __future__ import annotations

import importlib
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header


def header(stamp: Time, frame_id: str) -> Header:
    """A std_msgs/Header."""
    return Header(stamp=stamp, frame_id=frame_id)


def bgr8_image(image_bgr: np.ndarray, hdr: Header) -> Image:
    """A sensor_msgs/Image (bgr8) from ``image_bgr``: (H, W, 3) uint8 BGR."""
    arr = np.ascontiguousarray(image_bgr, dtype=np.uint8)
    h, w = arr.shape[:2]
    return Image(header=hdr, height=h, width=w, encoding="bgr8", is_bigendian=0, step=3 * w,
                 data=arr.tobytes())


def camera_info(result: Any, hdr: Header) -> CameraInfo:
    """A sensor_msgs/CameraInfo from a calibration result, with the same numbers as its YAML.

    Args:
        result: a CalibrationResult.
        hdr: header; frame_id should be the camera's optical frame (the images' frame_id).
    """
    from artcal_ros.core.camera_info import camera_info_fields

    fields = camera_info_fields(result)
    return CameraInfo(header=hdr, width=fields["width"], height=fields["height"],
                      distortion_model=fields["distortion_model"], d=fields["d"],
                      k=fields["k"], r=fields["r"], p=fields["p"])


def message_class(msgtype: str) -> type:
    """The Python class of a ROS message type name like ``sensor_msgs/msg/Image``.

    Raises:
        ImportError: the interface package is not installed; ValueError: a malformed name.
    """
    parts = msgtype.split("/")
    if len(parts) == 2:  # ROS 1 style "pkg/Type"
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"malformed message type {msgtype!r}; expected pkg/msg/Type")
    module = importlib.import_module(f"{parts[0]}.{parts[1]}")
    cls = getattr(module, parts[2], None)
    if cls is None:
        raise ImportError(f"{parts[0]}.{parts[1]} has no {parts[2]}")
    return cls  # type: ignore[no-any-return]
