"""The size a PNG or JPEG stream declares, read from its header before decoding it.

A damaged or hostile compressed frame can declare any size in a few bytes, and OpenCV
allocates the whole declared image before it finds the data missing. These checks refuse
such frames first, so decoding a frame costs at most what its bytes can really hold.
"""

from __future__ import annotations

import numpy as np

from artcal_ros.core.errors import ImageFormatError

__all__ = ["MAX_COMPRESSED_PIXELS", "check_compressed_header", "compressed_size"]


# A compressed frame declaring more pixels than this is refused before decoding: OpenCV would
# allocate the whole declared image (up to 1 Gpx) for a few bytes of data.
MAX_COMPRESSED_PIXELS = 100_000_000
# Pixels one byte of a stream can hold at most: deflate expands at most 1032-fold and a 1-bit
# PNG packs 8 pixels a byte; a Huffman-coded JPEG needs at least a bit per 8x8 block, so 512
# is its limit and 4096 leaves room for arithmetic coding. A header declaring more is damaged
# or the stream was cut short, and the decoder would fill the missing rows, allocating them.
_MAX_PIXELS_PER_BYTE = {"png": 8 * 1032, "jpeg": 4096}

_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
# JPEG start-of-frame markers (baseline, progressive, lossless, arithmetic); not DHT/JPG/DAC.
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}


def compressed_size(data: bytes | np.ndarray) -> tuple[int, int] | None:
    """(width, height) a PNG or JPEG stream declares in its header, without decoding it.

    Args:
        data: the compressed bytes (a flat uint8 array or bytes).

    Returns:
        (width, height) pixels, or None when the header is not a PNG's or a JPEG's or ends
        before the size.
    """
    head = bytes(data[:24]) if len(data) >= 24 else bytes(data)
    if head.startswith(_PNG_MAGIC) and head[12:16] == b"IHDR":
        return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    if not head.startswith(b"\xff\xd8"):
        return None
    raw = data if isinstance(data, bytes) else np.asarray(data, np.uint8).tobytes()
    pos = 2
    while pos + 4 <= len(raw):
        marker = raw[pos + 1]
        if raw[pos] != 0xFF or marker in (0x00, 0xFF):
            pos += 1  # fill or stray bytes: the decoder skips to the next marker, so do we
            continue
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # no length follows
            pos += 2
            continue
        length = int.from_bytes(raw[pos + 2 : pos + 4], "big")
        if marker in _JPEG_SOF:
            if pos + 9 > len(raw):
                return None
            height = int.from_bytes(raw[pos + 5 : pos + 7], "big")
            width = int.from_bytes(raw[pos + 7 : pos + 9], "big")
            return width, height
        if marker == 0xDA:  # start of scan before any frame header
            return None
        # libjpeg skips length - 2 bytes after the length field, and none when length < 2
        # (a damaged segment it reads through): so must we, or its size would go unchecked.
        pos += 2 + max(length, 2)
    return None


def check_compressed_header(buf: np.ndarray, codec: str) -> None:
    """Refuse what is not PNG or JPEG, and sizes that are empty or too large to decode.

    Args:
        buf: (N,) uint8, the compressed frame.
        codec: what the message's format field says ("png", "jpeg"), for the messages.

    Raises:
        ImageFormatError: naming the declared size or the first bytes, and what they mean.
    """
    if buf.size == 0:
        raise ImageFormatError(f"data is empty: a {codec} frame without bytes")
    head = bytes(buf[:8])
    if not (head.startswith(_PNG_MAGIC) or head.startswith(b"\xff\xd8")):
        raise ImageFormatError(
            f"data does not start like a PNG or JPEG file (first bytes {head!r}); the frame "
            f"is damaged, or format {codec!r} does not describe it"
        )
    size = compressed_size(buf)
    if size is None:
        return  # no readable size: the decoder decides
    width, height = size
    kind = "png" if head.startswith(_PNG_MAGIC) else "jpeg"
    if width == 0 or height == 0:
        raise ImageFormatError(f"the {kind} header declares an empty {width}x{height} image")
    if width * height > MAX_COMPRESSED_PIXELS:
        raise ImageFormatError(
            f"the {kind} header declares {width}x{height} pixels "
            f"({width * height / 1e6:.0f} Mpx), more than the {MAX_COMPRESSED_PIXELS / 1e6:.0f}"
            " Mpx artcal decodes; the frame is damaged or not a camera image"
        )
    if width * height > _MAX_PIXELS_PER_BYTE[kind] * buf.size:
        raise ImageFormatError(
            f"the {kind} header declares {width}x{height} pixels in only {buf.size} bytes, "
            f"more than a {kind} stream that short can hold; the frame is damaged or was "
            "cut short"
        )
