"""Glue between numpy / core results and ROS messages (no algorithms here)."""

from __future__ import annotations

import importlib

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Header

from artcal_ros.core.camera_info import CameraInfoData


def header(stamp: Time, frame_id: str) -> Header:
    """A std_msgs/Header."""
    return Header(stamp=stamp, frame_id=frame_id)


def bgr8_image(image_bgr: np.ndarray, hdr: Header) -> Image:
    """A sensor_msgs/Image (bgr8) from ``image_bgr``: (H, W, 3) uint8 BGR."""
    arr = np.ascontiguousarray(image_bgr, dtype=np.uint8)
    h, w = arr.shape[:2]
    return Image(header=hdr, height=h, width=w, encoding="bgr8", is_bigendian=0, step=3 * w,
                 data=arr.tobytes())


def camera_info(info: CameraInfoData, hdr: Header) -> CameraInfo:
    """A sensor_msgs/CameraInfo with the numbers of a calibration's YAML.

    Args:
        info: the calibration (``as_camera_info(result)`` of a CalibrationResult).
        hdr: header; frame_id should be the camera's optical frame (the images' frame_id).
    """
    def flat(a: np.ndarray) -> list[float]:
        return [float(v) for v in np.asarray(a, dtype=np.float64).ravel()]

    return CameraInfo(header=hdr, width=int(info.image_size[0]), height=int(info.image_size[1]),
                      distortion_model=info.distortion_model, d=flat(info.dist_coeffs),
                      k=flat(info.camera_matrix), r=flat(info.rectification_matrix),
                      p=flat(info.projection_matrix))


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
