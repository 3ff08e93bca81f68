"""The fields of an image message, duck-typed: an rclpy message, one decoded from a bag, or a
dict, with its ``data`` in any of the forms rclpy and the bag readers hand over.

Shared by :mod:`artcal_ros.core.images` (sensor_msgs/Image) and
:mod:`artcal_ros.core.images.compressed` (sensor_msgs/CompressedImage).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from artcal_ros.core.errors import ImageFormatError

__all__ = ["as_bytes", "get_field"]


def get_field(msg: Any, name: str) -> Any:
    """Field ``name`` of a message object or dict.

    Raises:
        ImageFormatError: the message has no such field.
    """
    if isinstance(msg, dict):
        if name not in msg:
            raise ImageFormatError(f"the image has no field {name!r}")
        return msg[name]
    try:
        return getattr(msg, name)
    except AttributeError:
        raise ImageFormatError(
            f"the image has no field {name!r} (expected a sensor_msgs/Image-like object)"
        ) from None


def as_bytes(data: Any) -> np.ndarray:
    """``data`` as a flat uint8 array, without a copy when the buffer allows it.

    Args:
        data: bytes, bytearray, memoryview, array.array, a list of ints 0..255 or a
            numpy array of them (int8 is read as its bytes).

    Returns:
        (N,) uint8, possibly a read-only view of ``data``.

    Raises:
        ImageFormatError: ``data`` is not a byte buffer or holds values outside 0..255.
    """
    if isinstance(data, bytes | bytearray | memoryview):
        try:
            return np.frombuffer(data, np.uint8)
        except (TypeError, ValueError):  # a memoryview of a non-contiguous buffer
            pass
    elif not isinstance(data, np.ndarray | str):
        try:
            return np.frombuffer(memoryview(data).cast("B"), np.uint8)  # array.array and friends
        except (TypeError, ValueError):
            pass
    try:
        arr = np.asarray(data)
    except Exception as err:  # any object may come in; none may escape
        raise ImageFormatError(f"data is not a byte buffer ({type(data).__name__})") from err
    if arr.dtype == np.uint8 or arr.dtype == np.int8:
        if arr.ndim == 0:
            raise ImageFormatError(f"data is a single number, not a byte buffer ({data!r})")
        return arr.reshape(-1).view(np.uint8)
    if arr.ndim == 0 or arr.dtype.kind not in "iu" or (
        arr.size and (arr.min() < 0 or arr.max() > 255)
    ):
        kind = f"an array of {arr.dtype.name}" if isinstance(data, np.ndarray) else (
            type(data).__name__)
        raise ImageFormatError(
            f"data is not a sequence of bytes ({kind}); expected bytes or uint8 values 0..255"
        )
    return arr.astype(np.uint8).reshape(-1)
