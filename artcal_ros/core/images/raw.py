"""sensor_msgs/Image <-> numpy, without cv_bridge and without ROS.

(sensor_msgs/CompressedImage is decoded by :mod:`artcal_ros.core.images.compressed`.)

Duck-typed: any object (or dict) with the message's fields works, whether an rclpy
message, a message decoded from a bag, or :func:`numpy_to_image`'s output. ``data`` may
be bytes, bytearray, memoryview, array.array, a list of ints or a numpy array.

Output conventions (what detection and calibration take):

- :func:`image_to_numpy`: mono encodings -> (H, W) uint8 or uint16; colour encodings (rgb,
  bgr, rgba, bgra, bayer, yuv422) -> (H, W, 3) BGR, uint8 or uint16
- :func:`image_to_gray`: (H, W) uint8 or uint16 for every encoding, what the detector
  reads, made from the message in one pass where OpenCV can (the luma of yuv422, a grey
  demosaic of bayer) instead of through a BGR copy

Row padding (``step`` > width * bytes per pixel) and big-endian 16-bit data are honoured.
mono and bgr images come back as views of the message buffer, without a copy: they may be
read-only and share memory with the message; copy before modifying them. Conversions
(channel order, alpha, demosaicing, YUV, byte swapping) return new arrays.
"""

from __future__ import annotations

import operator
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.errors import ImageFormatError
from artcal_ros.core.images.message_fields import as_bytes, get_field

__all__ = [
    "ENCODINGS",
    "ImageFormatError",
    "image_to_gray",
    "image_to_numpy",
    "numpy_to_image",
    "to_gray",
]


@dataclass(frozen=True)
class _Encoding:
    kind: str  # "mono" | "bgr" | "rgb" | "bgra" | "rgba" | "bayer" | "uyvy" | "yuyv"
    channels: int  # channels per pixel in the message buffer (2 bytes per pixel for yuv422)
    depth: int  # bytes per channel
    to_bgr: int = -1  # OpenCV conversion to image_to_numpy's output; -1: the buffer as is
    to_gray: int = -1  # OpenCV conversion to grey; -1: the buffer as is

    @property
    def bytes_per_pixel(self) -> int:
        return self.channels * self.depth


# OpenCV names Bayer patterns by the 2x2 block starting at the second row and column, so
# the ROS pattern RGGB is OpenCV's BG (the same mapping cv_bridge uses).
_BAYER = {
    "rggb": (cv2.COLOR_BayerBG2BGR, cv2.COLOR_BayerBG2GRAY),
    "bggr": (cv2.COLOR_BayerRG2BGR, cv2.COLOR_BayerRG2GRAY),
    "gbrg": (cv2.COLOR_BayerGR2BGR, cv2.COLOR_BayerGR2GRAY),
    "grbg": (cv2.COLOR_BayerGB2BGR, cv2.COLOR_BayerGB2GRAY),
}
_MONO = _Encoding("mono", 1, 1)
_MONO16 = _Encoding("mono", 1, 2)
_BGR = _Encoding("bgr", 3, 1, to_gray=cv2.COLOR_BGR2GRAY)
_BGR16 = _Encoding("bgr", 3, 2, to_gray=cv2.COLOR_BGR2GRAY)
_BGRA = _Encoding("bgra", 4, 1, cv2.COLOR_BGRA2BGR, cv2.COLOR_BGRA2GRAY)
_UYVY = _Encoding("uyvy", 2, 1, cv2.COLOR_YUV2BGR_UYVY, cv2.COLOR_YUV2GRAY_UYVY)
_YUYV = _Encoding("yuyv", 2, 1, cv2.COLOR_YUV2BGR_YUY2, cv2.COLOR_YUV2GRAY_YUY2)

ENCODINGS: dict[str, _Encoding] = {
    "mono8": _MONO,
    "8UC1": _MONO,
    "mono16": _MONO16,
    "16UC1": _MONO16,
    "bgr8": _BGR,
    "8UC3": _BGR,
    "rgb8": _Encoding("rgb", 3, 1, cv2.COLOR_RGB2BGR, cv2.COLOR_RGB2GRAY),
    "bgra8": _BGRA,
    "8UC4": _BGRA,
    "rgba8": _Encoding("rgba", 4, 1, cv2.COLOR_RGBA2BGR, cv2.COLOR_RGBA2GRAY),
    "bgr16": _BGR16,
    "16UC3": _BGR16,
    "rgb16": _Encoding("rgb", 3, 2, cv2.COLOR_RGB2BGR, cv2.COLOR_RGB2GRAY),
    "bgra16": _Encoding("bgra", 4, 2, cv2.COLOR_BGRA2BGR, cv2.COLOR_BGRA2GRAY),
    "rgba16": _Encoding("rgba", 4, 2, cv2.COLOR_RGBA2BGR, cv2.COLOR_RGBA2GRAY),
    **{f"bayer_{p}8": _Encoding("bayer", 1, 1, *codes) for p, codes in _BAYER.items()},
    **{f"bayer_{p}16": _Encoding("bayer", 1, 2, *codes) for p, codes in _BAYER.items()},
    "yuv422": _UYVY,
    "uyvy": _UYVY,
    "yuv422_yuy2": _YUYV,
    "yuyv": _YUYV,
}

# yuv422 from cameras is video range (BT.601: black at Y 16, white at 235), and OpenCV's
# YUV -> BGR expands it to 0..255; the grey path stretches the luma the same way, so a frame
# has the same grey levels (clipping, contrast) whichever path the node takes.
_VIDEO_GAIN = 255.0 / 219.0
_VIDEO_OFFSET = -16.0 * _VIDEO_GAIN


def _int_field(msg: Any, name: str) -> int:
    value = get_field(msg, name)
    number: int | None = None
    if not isinstance(value, bool | str | bytes):
        try:
            number = operator.index(value)  # int and numpy integers
        except TypeError:
            if isinstance(value, float | np.floating) and np.isfinite(value) and value == int(
                value
            ):
                number = int(value)
    if number is None:
        raise ImageFormatError(
            f"{name} must be an integer, not {value!r}; the message header is corrupt"
        )
    if number < 0:
        raise ImageFormatError(f"{name} must be >= 0, got {number}; the message header is corrupt")
    return number


def _big_endian(msg: Any) -> bool:
    value = _int_field(msg, "is_bigendian")
    if value > 1:
        raise ImageFormatError(
            f"is_bigendian must be 0 or 1, got {value}; the message header is corrupt"
        )
    return bool(value)


def _encoding_name(msg: Any) -> str:
    value = get_field(msg, "encoding")
    if isinstance(value, bytes):
        value = value.decode("ascii", "replace")
    if not isinstance(value, str):
        raise ImageFormatError(f"encoding must be a string, not {value!r}")
    return value


def lookup_encoding(encoding: Any) -> _Encoding:
    """The layout of a ROS image encoding name (exact, or differing only in case).

    Raises:
        ImageFormatError: unknown encoding; the message lists the supported ones.
    """
    name = str(encoding)
    found = ENCODINGS.get(name)
    if found is None:
        folded = {k.lower(): v for k, v in ENCODINGS.items()}
        found = folded.get(name.lower())
    if found is None:
        raise ImageFormatError(
            f"unknown encoding {name!r}; supported: {', '.join(ENCODINGS)}"
        )
    return found


def _buffer_pixels(msg: Any) -> tuple[np.ndarray, _Encoding, str]:
    """The header checked, and the pixels as an (H, W, channels) view of the buffer.

    16-bit data comes in native byte order (a copy only when the bytes must be swapped or
    the rows start at odd addresses); the padding at the end of each row is skipped by the
    view, not copied.
    """
    height = _int_field(msg, "height")
    width = _int_field(msg, "width")
    encoding = _encoding_name(msg)
    enc = lookup_encoding(encoding)
    step = _int_field(msg, "step")
    big_endian = _big_endian(msg)
    if height == 0 or width == 0:
        raise ImageFormatError(
            f"the image is empty (height {height}, width {width}); the camera driver sent a "
            "frame without pixels"
        )
    row_bytes = width * enc.bytes_per_pixel
    if step < row_bytes:
        raise ImageFormatError(
            f"step {step} < width*bytes_per_pixel {row_bytes} for {encoding} "
            f"(width {width}, {enc.bytes_per_pixel} bytes per pixel); step must be at least "
            "one row of pixels: the header is corrupt or encoding names the wrong format"
        )
    if enc.kind in ("uyvy", "yuyv") and width % 2:
        raise ImageFormatError(f"width {width} must be even for {encoding} (2 pixels share U, V)")
    buf = as_bytes(get_field(msg, "data"))
    if buf.size != step * height:
        raise ImageFormatError(
            f"data has {buf.size} bytes, expected step*height = {step * height} "
            f"(step {step}, height {height}); the frame was cut short or its header is wrong"
        )
    rows = buf.reshape(height, step)[:, :row_bytes]
    if enc.depth == 2:
        rows = rows.view(">u2" if big_endian else "<u2")
        rows = rows.view(np.uint16) if rows.dtype.isnative else rows.astype(np.uint16)
        if not rows.flags.aligned:
            # an odd step starts rows at odd addresses: OpenCV refuses such arrays
            rows = np.ascontiguousarray(rows)
    return rows.reshape(height, width, enc.channels), enc, encoding


def _convert(pixels: np.ndarray, code: int, encoding: str) -> np.ndarray:
    """``pixels`` through OpenCV conversion ``code``; with code -1, the buffer as it is."""
    # cvtColor reads row-padded views as they are: no contiguous copy first.
    src = pixels[:, :, 0] if pixels.shape[2] == 1 else pixels
    if code < 0:
        return src
    try:
        return cv2.cvtColor(src, code)
    except cv2.error as err:  # e.g. a mosaic too small to demosaic
        height, width = pixels.shape[:2]
        raise ImageFormatError(
            f"a {width}x{height} {encoding} image cannot be converted "
            f"({err.msg.strip() if hasattr(err, 'msg') else err})"
        ) from None


def image_to_numpy(msg: Any) -> np.ndarray:
    """Pixels of a sensor_msgs/Image as a numpy array.

    Args:
        msg: object or dict with ``height``, ``width``, ``encoding``, ``is_bigendian``,
            ``step`` (bytes per row) and ``data`` (step * height bytes).

    Returns:
        (H, W) uint8/uint16 for mono encodings; (H, W, 3) BGR uint8/uint16 otherwise.

    Raises:
        ImageFormatError: naming the field that is wrong (encoding, step, data, width...).
    """
    pixels, enc, encoding = _buffer_pixels(msg)
    return _convert(pixels, enc.to_bgr, encoding)


def image_to_gray(msg: Any) -> np.ndarray:
    """The grey image detection reads, straight from a sensor_msgs/Image.

    The same grey levels as ``to_gray(image_to_numpy(msg))`` (to rounding), without the
    BGR image in between: mono8/mono16 come back as views of the buffer, yuv422 as its
    stretched luma, bayer demosaiced to grey, rgb/bgr(a) in one conversion.

    Args:
        msg: as for :func:`image_to_numpy`.

    Returns:
        (H, W) uint8 or uint16 (16-bit encodings).

    Raises:
        ImageFormatError: naming the field that is wrong (encoding, step, data, width...).
    """
    pixels, enc, encoding = _buffer_pixels(msg)
    gray = _convert(pixels, enc.to_gray, encoding)
    if enc.kind in ("uyvy", "yuyv"):
        cv2.convertScaleAbs(gray, dst=gray, alpha=_VIDEO_GAIN, beta=_VIDEO_OFFSET)
    return gray


def to_gray(image: np.ndarray) -> np.ndarray:
    """A single-channel image for detection, in the input's dtype.

    Args:
        image: (H, W) or (H, W, 1) as is; (H, W, 3) BGR or (H, W, 4) BGRA, uint8/uint16.

    Returns:
        (H, W) uint8 or uint16.
    """
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[:, :, 0]
    if arr.ndim == 2:
        return arr
    if arr.ndim == 3 and arr.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if arr.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        return cv2.cvtColor(np.ascontiguousarray(arr), code)
    raise ImageFormatError(
        f"cannot make a grey image from an array of shape {arr.shape}; expected (H, W), "
        "(H, W, 3) BGR or (H, W, 4) BGRA"
    )


def numpy_to_image(
    image: np.ndarray, encoding: str = "mono8", stamp_ns: int = 0, frame_id: str = "camera"
) -> dict[str, Any]:
    """The fields of a sensor_msgs/Image holding ``image`` in ``encoding``.

    Args:
        image: (H, W) uint8/uint16 for mono encodings; (H, W, 3) BGR (or (H, W, 4) BGRA)
            for colour ones, converted to the encoding's channel order; for bayer
            encodings either (H, W) raw mosaic or (H, W, 3) BGR to be sampled; for yuv422
            (H, W, 3) BGR uint8 with even W.
        encoding: a ROS image encoding (see ENCODINGS).
        stamp_ns: header stamp, nanoseconds since the epoch.
        frame_id: header frame.

    Returns:
        dict with ``header`` {stamp {sec, nanosec}, frame_id}, ``height``, ``width``,
        ``encoding``, ``is_bigendian`` (0), ``step`` (no padding) and ``data`` (bytes).

    Raises:
        ImageFormatError: the array's shape or dtype does not fit the encoding.
    """
    enc = lookup_encoding(encoding)
    arr = np.asarray(image)
    dtype = np.uint8 if enc.depth == 1 else np.uint16
    if arr.dtype != dtype:
        raise ImageFormatError(
            f"{encoding} needs a {np.dtype(dtype).name} array, got {arr.dtype.name}"
        )
    packed = _pack(arr, enc, encoding)
    height, width = arr.shape[:2]
    stamp_ns = int(stamp_ns)
    return {
        "header": {
            "stamp": {"sec": stamp_ns // 1_000_000_000, "nanosec": stamp_ns % 1_000_000_000},
            "frame_id": frame_id,
        },
        "height": int(height),
        "width": int(width),
        "encoding": encoding,
        "is_bigendian": 0,
        "step": int(width) * enc.bytes_per_pixel,
        "data": packed.astype(packed.dtype.newbyteorder("<"), copy=False).tobytes(),
    }


def _pack(arr: np.ndarray, enc: _Encoding, encoding: str) -> np.ndarray:
    """``arr`` in the buffer layout of ``enc``: (H, W) or (H, W, channels)."""
    colour = arr.ndim == 3 and arr.shape[2] in (3, 4)
    if enc.kind == "mono":
        if arr.ndim != 2:
            raise ImageFormatError(f"{encoding} needs an (H, W) array, got shape {arr.shape}")
        return arr
    if enc.kind == "bayer" and arr.ndim == 2:
        return arr  # already a mosaic
    if not colour:
        raise ImageFormatError(
            f"{encoding} needs an (H, W, 3) BGR array, got shape {arr.shape}"
        )
    bgr = arr[:, :, :3]
    if enc.kind == "bgr":
        return bgr
    if enc.kind == "rgb":
        return bgr[:, :, ::-1]
    if enc.kind in ("bgra", "rgba"):
        opaque = np.iinfo(arr.dtype).max
        alpha = arr[:, :, 3:] if arr.shape[2] == 4 else np.full_like(arr[:, :, :1], opaque)
        body = bgr if enc.kind == "bgra" else bgr[:, :, ::-1]
        return np.concatenate([body, alpha], axis=2)
    if enc.kind == "bayer":
        return _mosaic(bgr, encoding)
    if arr.shape[1] % 2:
        raise ImageFormatError(f"width {arr.shape[1]} must be even for {encoding}")
    code = cv2.COLOR_BGR2YUV_UYVY if enc.kind == "uyvy" else cv2.COLOR_BGR2YUV_YUY2
    return cv2.cvtColor(np.ascontiguousarray(bgr), code)


def _mosaic(bgr: np.ndarray, encoding: str) -> np.ndarray:
    """Sample a BGR image through the colour filter array named in ``encoding``."""
    pattern = encoding.split("_")[1][:4].lower()  # e.g. "rggb"
    channel = {"b": 0, "g": 1, "r": 2}
    out = np.empty(bgr.shape[:2], bgr.dtype)
    for i, letter in enumerate(pattern):
        dy, dx = divmod(i, 2)
        out[dy::2, dx::2] = bgr[dy::2, dx::2, channel[letter]]
    return out
