"""sensor_msgs/CompressedImage (jpeg, png) -> numpy, without cv_bridge and without ROS.

Duck-typed as :mod:`artcal_ros.core.images` is: any object (or dict) with ``format`` and
``data`` works. The header is checked before decoding
(:func:`~artcal_ros.core.images.compressed_header.check_compressed_header`), so a damaged frame
cannot make OpenCV allocate more than its bytes can hold.

Output conventions (as for sensor_msgs/Image in :mod:`artcal_ros.core.images`):

- :func:`compressed_to_numpy`: (H, W) uint8 or uint16 for grey images, (H, W, 3) BGR for
  colour ones, whatever channel order image_transport's format field names
- :func:`compressed_to_gray`: (H, W) uint8 or uint16, what the detector reads; a jpeg is
  decoded to its luma alone instead of through a BGR copy
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.errors import ImageFormatError
from artcal_ros.core.images.compressed_header import check_compressed_header
from artcal_ros.core.images.message_fields import as_bytes, get_field

__all__ = ["compressed_to_gray", "compressed_to_numpy"]


@dataclass(frozen=True)
class _CompressedFrame:
    codec: str  # "jpeg" | "jpg" | "png", as the format field names it
    data: np.ndarray  # (N,) uint8, the compressed stream, its header checked
    mono: bool  # the camera's image was grey (image_transport's first encoding)
    rgb_order: bool  # the codec was given RGB pixels as if BGR (a "compressed rgb8" target)


def _compressed_frame(msg: Any) -> _CompressedFrame:
    """The format field read, and the data checked, of a CompressedImage."""
    fmt = str(get_field(msg, "format")).strip()
    original, _, compressed = fmt.partition(";")
    described = (compressed or original).strip().lower()
    codec: str | None = next((c for c in ("jpeg", "jpg", "png") if c in described.split()), None)
    if codec is None and described in ("", "jpeg", "jpg", "png"):
        codec = described or None
    if codec is None or "compresseddepth" in fmt.lower():
        raise ImageFormatError(
            f"format {fmt!r} is not supported; expected 'jpeg', 'png' or image_transport's "
            "'<encoding>; jpeg compressed <encoding>'"
        )
    buf = as_bytes(get_field(msg, "data"))
    check_compressed_header(buf, codec)
    # image_transport names the channel order of the compressed pixels after the codec;
    # the codec itself stores what it was given as BGR, so "compressed rgb8" is swapped.
    target = described.split()[-1] if compressed else ""
    mono = original.strip().lower().startswith(("mono", "8uc1", "16uc1"))
    return _CompressedFrame(codec, buf, mono, target.startswith("rgb"))


def _decode(frame: _CompressedFrame, flags: int) -> np.ndarray:
    try:
        image = cv2.imdecode(frame.data, flags)
    except cv2.error:
        image = None
    if image is None or image.dtype not in (np.uint8, np.uint16) or image.size == 0:
        raise ImageFormatError(
            f"data ({frame.data.size} bytes) does not decode as a {frame.codec} image; the "
            "frame is damaged or was cut short"
        )
    return image


def compressed_to_numpy(msg: Any) -> np.ndarray:
    """Pixels of a sensor_msgs/CompressedImage (jpeg or png).

    Args:
        msg: object or dict with ``format`` ("jpeg", "png", or image_transport's
            "<encoding>; <jpeg|png> compressed <encoding>") and ``data``.

    Returns:
        (H, W) uint8/uint16 for grey images, (H, W, 3) BGR uint8/uint16 for colour ones.

    Raises:
        ImageFormatError: unsupported format, or data that does not decode.
    """
    frame = _compressed_frame(msg)
    if frame.mono:
        return _gray_decode(frame)
    image = _decode(frame, cv2.IMREAD_UNCHANGED)
    if image.ndim == 3 and image.shape[2] == 4:
        image = cv2.cvtColor(image, cv2.COLOR_RGBA2BGR if frame.rgb_order else cv2.COLOR_BGRA2BGR)
    elif image.ndim == 3 and frame.rgb_order:
        image = cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
    return image


def compressed_to_gray(msg: Any) -> np.ndarray:
    """The grey image detection reads, straight from a sensor_msgs/CompressedImage.

    The same grey levels as ``to_gray(compressed_to_numpy(msg))`` (a jpeg's to rounding): a
    jpeg is decoded to its luma only, without converting its colour.

    Args:
        msg: as for :func:`compressed_to_numpy`.

    Returns:
        (H, W) uint8, or uint16 for a 16-bit png.

    Raises:
        ImageFormatError: unsupported format, or data that does not decode.
    """
    return _gray_decode(_compressed_frame(msg))


def _gray_decode(frame: _CompressedFrame) -> np.ndarray:
    # A jpeg stores luma apart from chroma: decoding the luma alone skips the chroma's
    # upsampling and colour conversion. Its luma weighs red as blue in a "compressed rgb8"
    # stream, though, and libpng's own grey conversion rounds unlike OpenCV's; those are
    # decoded in colour and weighed here.
    if frame.codec != "png" and not frame.rgb_order:
        return _decode(frame, cv2.IMREAD_GRAYSCALE | cv2.IMREAD_ANYDEPTH)
    image = _decode(frame, cv2.IMREAD_UNCHANGED)
    if image.ndim == 2:
        return image
    if frame.rgb_order:
        code = cv2.COLOR_RGBA2GRAY if image.shape[2] == 4 else cv2.COLOR_RGB2GRAY
    else:
        code = cv2.COLOR_BGRA2GRAY if image.shape[2] == 4 else cv2.COLOR_BGR2GRAY
    return cv2.cvtColor(image, code)
