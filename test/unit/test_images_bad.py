"""Bad sensor_msgs/Image and CompressedImage messages: every one is refused with an
ImageFormatError that names the field, and nothing else escapes (explicit cases for every
supported encoding, then property-based fuzzing of the converters, to BGR and to grey)."""

from __future__ import annotations

import struct
import tracemalloc
import zlib
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from artcal_ros.core.images import ENCODINGS, ImageFormatError, image_to_gray, image_to_numpy
from artcal_ros.core.images.compressed import compressed_to_gray, compressed_to_numpy
from artcal_ros.core.images.compressed_header import compressed_size


def msg(height: Any = 4, width: Any = 4, encoding: Any = "mono8", step: Any = None,
        data: Any = None, is_bigendian: Any = 0) -> SimpleNamespace:
    """A message with a consistent header unless a field is given."""
    bpp = ENCODINGS[encoding].bytes_per_pixel if encoding in ENCODINGS else 1
    if step is None:
        step = width * bpp if isinstance(width, int) else 4
    if data is None:
        data = bytes(step * height) if isinstance(step, int) and isinstance(height, int) else b""
    return SimpleNamespace(height=height, width=width, encoding=encoding, step=step,
                           data=data, is_bigendian=is_bigendian)


EVERY_ENCODING = sorted(ENCODINGS)
# Both entry points read the header the same way and must refuse the same messages.
CONVERTERS = [image_to_numpy, image_to_gray]
COMPRESSED_CONVERTERS = [compressed_to_numpy, compressed_to_gray]


@pytest.mark.parametrize("image_to_numpy", CONVERTERS)
@pytest.mark.parametrize("encoding", EVERY_ENCODING)
def test_every_encoding_refuses_a_bad_step_short_and_long_data_and_zero_size(
        encoding: str, image_to_numpy: Any) -> None:
    bpp = ENCODINGS[encoding].bytes_per_pixel
    good = msg(4, 4, encoding)
    assert image_to_numpy(good).shape[:2] == (4, 4)
    with pytest.raises(ImageFormatError, match=rf"step {4 * bpp - 1} < width\*bytes_per_pixel "
                                               rf"{4 * bpp} for {encoding}.*header is corrupt"):
        image_to_numpy(msg(4, 4, encoding, step=4 * bpp - 1, data=bytes((4 * bpp - 1) * 4)))
    with pytest.raises(ImageFormatError, match=rf"data has {16 * bpp - 1} bytes, expected "
                                               rf"step\*height = {16 * bpp}.*cut short"):
        image_to_numpy(msg(4, 4, encoding, data=bytes(16 * bpp - 1)))
    with pytest.raises(ImageFormatError, match=rf"data has {16 * bpp + 1} bytes"):
        image_to_numpy(msg(4, 4, encoding, data=bytes(16 * bpp + 1)))
    with pytest.raises(ImageFormatError, match=r"the image is empty \(height 0, width 4\)"):
        image_to_numpy(msg(0, 4, encoding))
    with pytest.raises(ImageFormatError, match=r"the image is empty \(height 4, width 0\)"):
        image_to_numpy(msg(4, 0, encoding, step=0, data=b""))


@pytest.mark.parametrize("image_to_numpy", CONVERTERS)
@pytest.mark.parametrize("encoding", EVERY_ENCODING)
def test_huge_declared_dimensions_are_refused_before_any_allocation(
        encoding: str, image_to_numpy: Any) -> None:
    bpp = ENCODINGS[encoding].bytes_per_pixel
    huge = msg(100_000, 100_000, encoding, step=100_000 * bpp, data=bytes(1000))
    tracemalloc.start()
    try:
        with pytest.raises(ImageFormatError, match=r"data has 1000 bytes, expected step\*height"):
            image_to_numpy(huge)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1_000_000  # 100000 x 100000 would be 10 GB or more


BAD_HEADERS = {
    # field value -> what the message must say
    "height 2.5": (msg(height=2.5), r"height must be an integer, not 2\.5"),
    "height inf": (msg(height=float("inf")), r"height must be an integer, not inf"),
    "height nan": (msg(height=float("nan")), r"height must be an integer, not nan"),
    "height True": (msg(height=True), r"height must be an integer, not True"),
    "height '4'": (msg(height="4"), r"height must be an integer, not '4'"),
    "width negative": (msg(width=-4, step=4), r"width must be >= 0, got -4"),
    "step None": (SimpleNamespace(height=4, width=4, encoding="mono8", step=None,
                                  data=bytes(16), is_bigendian=0),
                  r"step must be an integer, not None"),
    "is_bigendian 2": (msg(is_bigendian=2), r"is_bigendian must be 0 or 1, got 2"),
    "is_bigendian 'yes'": (msg(is_bigendian="yes"), r"is_bigendian must be an integer"),
    "encoding None": (msg(encoding=None, step=4, data=bytes(16)),
                      r"encoding must be a string, not None"),
    "unknown encoding": (msg(encoding="yuv_weird", step=4, data=bytes(16)),
                         r"unknown encoding 'yuv_weird'; supported: mono8"),
    "data None": (SimpleNamespace(height=4, width=4, encoding="mono8", step=4, data=None,
                                  is_bigendian=0), r"data is not a sequence of bytes \(NoneType"),
    "data float array": (msg(data=np.zeros(16, np.float32)),
                         r"data is not a sequence of bytes \(an array of float32\)"),
    "data NaN array": (msg(data=np.full(16, np.nan)),
                       r"data is not a sequence of bytes \(an array of float64\)"),
    "data object array": (msg(data=np.array([object()] * 16)),
                          r"data is not a sequence of bytes \(an array of object\)"),
    "data bool array": (msg(data=np.ones(16, bool)),
                        r"data is not a sequence of bytes \(an array of bool\)"),
    "data a number": (msg(data=7), r"data is not a sequence of bytes \(int\)"),
    "data a string": (msg(data="x" * 16), r"data is not a sequence of bytes \(str\)"),
    "data ragged list": (msg(data=[[1, 2], [3]]), r"data is not a byte buffer \(list\)"),
}


@pytest.mark.parametrize("image_to_numpy", CONVERTERS)
@pytest.mark.parametrize("case", list(BAD_HEADERS))
def test_bad_header_fields_are_named(case: str, image_to_numpy: Any) -> None:
    bad, pattern = BAD_HEADERS[case]
    with pytest.raises(ImageFormatError, match=pattern):
        image_to_numpy(bad)


@pytest.mark.parametrize("image_to_numpy", CONVERTERS)
@pytest.mark.parametrize("encoding", [e for e in EVERY_ENCODING if ENCODINGS[e].depth == 2])
def test_big_endian_16_bit_is_byte_swapped(encoding: str, image_to_numpy: Any) -> None:
    channels = ENCODINGS[encoding].channels
    values = np.arange(4 * 4 * channels, dtype=np.uint16).reshape(4, 4, channels) * 1000
    big = msg(4, 4, encoding, data=values.astype(">u2").tobytes(), is_bigendian=1)
    little = msg(4, 4, encoding, data=values.astype("<u2").tobytes(), is_bigendian=0)
    out = image_to_numpy(big)
    assert out.dtype == np.uint16
    np.testing.assert_array_equal(out, image_to_numpy(little))


# -- compressed ------------------------------------------------------------------------------


def png_header(width: int, height: int, body: bytes = b"") -> bytes:
    """A PNG whose IHDR declares width x height grey 8-bit pixels, with ``body`` as its data."""
    def chunk(kind: bytes, payload: bytes) -> bytes:
        crc = zlib.crc32(kind + payload) & 0xFFFFFFFF
        return struct.pack(">I", len(payload)) + kind + payload + struct.pack(">I", crc)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(body))
            + chunk(b"IEND", b""))


def jpeg_declaring(width: int, height: int) -> bytes:
    """An 8x8 JPEG whose frame header is patched to declare width x height."""
    data = bytearray(cv2.imencode(".jpg", np.zeros((8, 8), np.uint8))[1].tobytes())
    sof = data.find(b"\xff\xc0")
    data[sof + 5 : sof + 9] = struct.pack(">HH", height, width)
    return bytes(data)


def test_compressed_size_reads_png_and_jpeg_headers() -> None:
    image = np.zeros((37, 53, 3), np.uint8)
    for ext in (".png", ".jpg"):
        assert compressed_size(cv2.imencode(ext, image)[1].tobytes()) == (53, 37)
    assert compressed_size(png_header(100_000, 7)) == (100_000, 7)
    assert compressed_size(jpeg_declaring(65000, 3)) == (65000, 3)
    assert compressed_size(b"\xff\xd8\xff") is None and compressed_size(b"junk") is None


BAD_COMPRESSED = {
    "empty data": ("png", b"", r"data is empty: a png frame without bytes"),
    "not an image": ("jpeg", b"hello", r"data does not start like a PNG or JPEG file"),
    "TIFF called png": ("png", cv2.imencode(".tiff", np.zeros((8, 8), np.float32))[1].tobytes(),
                        r"first bytes b'II\*\\x00"),
    "truncated PNG": ("png", cv2.imencode(".png", np.eye(64, dtype=np.uint8))[1].tobytes()[:60],
                      r"data \(60 bytes\) does not decode as a png image; the frame is damaged"),
    "PNG 100000 x 100000": ("png", png_header(100_000, 100_000),
                            r"png header declares 100000x100000 pixels \(10000 Mpx\), more than"),
    "PNG zero width": ("png", png_header(0, 8), r"declares an empty 0x8 image"),
    "JPEG 65000 x 65000": ("jpeg", jpeg_declaring(65000, 65000),
                           r"jpeg header declares 65000x65000 pixels \(4225 Mpx\)"),
    # a segment length below 2 that libjpeg reads through must not hide the frame header
    "JPEG 65000 x 65000 after a zero-length APP0": (
        "jpeg", jpeg_declaring(65000, 65000)[:4] + b"\0\0" + jpeg_declaring(65000, 65000)[6:],
        r"jpeg header declares 65000x65000 pixels"),
    "JPEG 6000 x 6000 in 300 bytes": ("jpeg", jpeg_declaring(6000, 6000),
                                        r"declares 6000x6000 pixels in only \d+ bytes"),
    "format None": (None, b"x", r"format 'None' is not supported"),
    "data None": ("png", None, r"data is not a sequence of bytes \(NoneType\)"),
}


@pytest.mark.parametrize("compressed_to_numpy", COMPRESSED_CONVERTERS)
@pytest.mark.parametrize("case", list(BAD_COMPRESSED))
def test_bad_compressed_frames_are_refused_without_decoding_huge_headers(
        case: str, compressed_to_numpy: Any) -> None:
    fmt, data, pattern = BAD_COMPRESSED[case]
    tracemalloc.start()
    try:
        with pytest.raises(ImageFormatError, match=pattern):
            compressed_to_numpy(SimpleNamespace(format=fmt, data=data))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 2_000_000


# -- property-based: random headers and data ------------------------------------------------

ENCODING_NAMES = st.sampled_from([*EVERY_ENCODING, "yuv_weird", "", "MONO8", "bgr", "16UC2"])
SIZES = st.one_of(st.integers(0, 12), st.sampled_from([100_000, 2**31, 2**64]),
                  st.integers(-3, -1))


# header fields as a corrupt or hand-made message may carry them
ODD_NUMBERS = st.sampled_from([2.0, 2.5, float("inf"), float("nan"), None, "3"])


def _count(value: Any) -> int:
    """How many rows or bytes a header value stands for, in the test's own arithmetic."""
    ok = isinstance(value, int) or (isinstance(value, float) and value.is_integer())
    return max(int(value), 0) if ok else 0


@st.composite
def image_messages(draw: st.DrawFn) -> SimpleNamespace:
    encoding = draw(ENCODING_NAMES)
    height = draw(st.one_of(SIZES, ODD_NUMBERS))
    width = draw(st.one_of(SIZES, ODD_NUMBERS))
    bpp = ENCODINGS[encoding].bytes_per_pixel if encoding in ENCODINGS else 1
    natural = _count(width) * bpp
    step = draw(st.one_of(st.just(natural), st.integers(0, 64), SIZES, ODD_NUMBERS,
                          st.just(natural + draw(st.integers(1, 5)))))
    consistent = _count(step) * _count(height)
    length = draw(st.one_of(st.just(consistent), st.integers(0, 300)).filter(
        lambda n: n <= 20_000))
    data = draw(st.binary(min_size=length, max_size=length)) if length < 512 else bytes(length)
    wrap = draw(st.sampled_from([bytes, bytearray, np.frombuffer, list]))
    payload = wrap(data) if wrap is not np.frombuffer else np.frombuffer(data, np.uint8)
    return SimpleNamespace(height=height, width=width, encoding=encoding, step=step,
                           data=payload, is_bigendian=draw(st.sampled_from([0, 1, 2, True])))


@settings(derandomize=True, max_examples=400, deadline=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(image_messages())
def test_fuzzed_images_give_the_declared_shape_or_image_format_error(m: SimpleNamespace) -> None:
    try:
        out = image_to_numpy(m)
    except ImageFormatError as err:
        assert str(err)
        with pytest.raises(ImageFormatError):
            image_to_gray(m)
        return
    enc = ENCODINGS.get(m.encoding) or ENCODINGS[{e.lower(): e for e in ENCODINGS}[
        m.encoding.lower()]]
    expected = (m.height, m.width) if enc.kind == "mono" else (m.height, m.width, 3)
    assert isinstance(out, np.ndarray) and out.shape == expected
    assert out.dtype == (np.uint8 if enc.depth == 1 else np.uint16)
    gray = image_to_gray(m)
    assert gray.shape == (m.height, m.width) and gray.dtype == out.dtype


def _valid_streams() -> list[bytes]:
    rng = np.random.default_rng(3)
    grey = rng.integers(0, 256, (12, 10), dtype=np.uint8)
    colour = rng.integers(0, 256, (9, 14, 3), dtype=np.uint8)
    return [cv2.imencode(".png", grey)[1].tobytes(),
            cv2.imencode(".png", colour.astype(np.uint16) * 257)[1].tobytes(),
            cv2.imencode(".jpg", colour)[1].tobytes(),
            cv2.imencode(".jpg", grey)[1].tobytes()]


VALID_STREAMS = _valid_streams()
HEADER_SIZES = st.sampled_from([0, 1, 3, 9, 14, 640, 6000, 40_000, 65_535, 2**31 - 1])


@st.composite
def damaged_streams(draw: st.DrawFn) -> bytes:
    data = bytearray(draw(st.sampled_from(VALID_STREAMS)))
    for _ in range(draw(st.integers(0, 4))):
        action = draw(st.sampled_from(["flip", "cut", "insert", "dims"]))
        where = draw(st.integers(0, max(len(data) - 1, 0)))
        if action == "flip" and data:
            data[where] ^= draw(st.integers(1, 255))
        elif action == "cut":
            del data[where:]
        elif action == "insert":
            data[where:where] = draw(st.binary(min_size=1, max_size=16))
        elif action == "dims":  # declare another size: tiny, huge, or empty
            w, h = draw(HEADER_SIZES), draw(HEADER_SIZES)
            sof = data.find(b"\xff\xc0")
            if data[:4] == b"\x89PNG" and len(data) > 24:
                data[16:24] = struct.pack(">II", w, h)
                data[29:33] = struct.pack(">I", zlib.crc32(data[12:29]) & 0xFFFFFFFF)
            elif sof > 0 and len(data) > sof + 9:
                data[sof + 5 : sof + 9] = struct.pack(">HH", h % 2**16, w % 2**16)
    return bytes(data)


@settings(derandomize=True, max_examples=300, deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(damaged_streams(), st.sampled_from(["png", "jpeg", "rgb8; jpeg compressed bgr8",
                                           "mono8; png compressed mono8",
                                           "rgb8; png compressed rgb8", "theora", ""]))
def test_fuzzed_compressed_frames_decode_or_raise_image_format_error(data: bytes,
                                                                     fmt: str) -> None:
    # A damaged jpeg may decode to grey and not in colour: each converter is judged alone.
    for convert in COMPRESSED_CONVERTERS:
        try:
            out = convert(SimpleNamespace(format=fmt, data=data))
        except ImageFormatError as err:
            assert str(err)
            continue
        assert isinstance(out, np.ndarray) and out.dtype in (np.uint8, np.uint16)
        assert out.ndim == 2 or (out.ndim == 3 and out.shape[2] == 3)
        assert convert is compressed_to_numpy or out.ndim == 2
        size = compressed_size(data)
        assert size is not None and out.shape[1::-1] == size
