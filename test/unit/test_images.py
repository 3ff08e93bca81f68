"""sensor_msgs/Image <-> numpy: hand-built buffers for every encoding, the grey path against
the grey of a known image, and every error."""

from __future__ import annotations

import array
import struct
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np
import pytest

from artcal_ros.core.images import (
    ENCODINGS,
    ImageFormatError,
    image_to_gray,
    image_to_numpy,
    numpy_to_image,
    to_gray,
)
from artcal_ros.core.images.compressed import compressed_to_gray, compressed_to_numpy

# A colour with distinct channels, so swapped or mixed channels show.
R, G, B = 200, 100, 30


def msg(height: int, width: int, encoding: str, step: int, data: Any,
        is_bigendian: int = 0) -> SimpleNamespace:
    return SimpleNamespace(height=height, width=width, encoding=encoding, step=step,
                           data=data, is_bigendian=is_bigendian)


def padded(rows: list[bytes], step: int) -> bytes:
    """Rows of pixel bytes, each padded with 0xEE up to ``step`` bytes."""
    return b"".join(r + b"\xee" * (step - len(r)) for r in rows)


# -- mono ------------------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", ["mono8", "8UC1"])
def test_mono8_with_row_padding_is_a_view(encoding: str) -> None:
    rows = [bytes([10 * r + c for c in range(5)]) for r in range(3)]
    buf = bytearray(padded(rows, 8))
    out = image_to_numpy(msg(3, 5, encoding, 8, buf))
    assert out.shape == (3, 5) and out.dtype == np.uint8
    np.testing.assert_array_equal(out, [[10 * r + c for c in range(5)] for r in range(3)])
    assert np.shares_memory(out, np.frombuffer(buf, np.uint8))  # no copy


@pytest.mark.parametrize("encoding", ["mono16", "16UC1"])
@pytest.mark.parametrize("big_endian", [0, 1])
def test_mono16_byte_order_and_padding(encoding: str, big_endian: int) -> None:
    values = [[0x0102, 0xABCD, 0xFFFF], [0x0000, 0x8001, 0x1234]]
    fmt = ">3H" if big_endian else "<3H"
    step = 3 * 2 + 3  # odd padding: rows start at odd offsets
    data = padded([struct.pack(fmt, *row) for row in values], step)
    out = image_to_numpy(msg(2, 3, encoding, step, data, is_bigendian=big_endian))
    assert out.dtype == np.uint16 and out.dtype.isnative and out.shape == (2, 3)
    np.testing.assert_array_equal(out, values)


# -- colour ----------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("encoding", "pixel"),
    [
        ("bgr8", (B, G, R)),
        ("8UC3", (B, G, R)),
        ("rgb8", (R, G, B)),
        ("bgra8", (B, G, R, 77)),
        ("rgba8", (R, G, B, 77)),
    ],
)
def test_colour8_known_pixel(encoding: str, pixel: tuple[int, ...]) -> None:
    n = len(pixel)
    other = bytes([1, 2, 3, 4][:n])
    rows = [bytes(pixel) + other, other + other]  # 2x2, pixel (0, 0) is the colour
    out = image_to_numpy(msg(2, 2, encoding, 2 * n + 2, padded(rows, 2 * n + 2)))
    assert out.shape == (2, 2, 3) and out.dtype == np.uint8
    assert tuple(out[0, 0]) == (B, G, R)
    expected_other = (1, 2, 3) if encoding.startswith(("bgr", "8UC")) else (3, 2, 1)
    assert tuple(out[1, 1]) == expected_other


@pytest.mark.parametrize("encoding", ["bgr16", "rgb16"])
@pytest.mark.parametrize("big_endian", [0, 1])
def test_colour16_known_pixel(encoding: str, big_endian: int) -> None:
    b, g, r = 0x0102, 0x7FFE, 0xF00D
    order = (b, g, r) if encoding == "bgr16" else (r, g, b)
    pix = struct.pack(">3H" if big_endian else "<3H", *order)
    out = image_to_numpy(msg(1, 2, encoding, 14, pix + pix + b"\0\0", is_bigendian=big_endian))
    assert out.shape == (1, 2, 3) and out.dtype == np.uint16
    assert tuple(out[0, 1]) == (b, g, r)


def bayer_mosaic(pattern: str, h: int, w: int, rgb: tuple[int, int, int]) -> np.ndarray:
    """A uniform colour seen through the colour filter array ``pattern`` (e.g. "rggb")."""
    value = dict(zip("rgb", rgb, strict=True))
    out = np.zeros((h, w), np.uint16)
    for y in range(h):
        for x in range(w):
            out[y, x] = value[pattern[(y % 2) * 2 + (x % 2)]]
    return out


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
@pytest.mark.parametrize("depth", [8, 16])
def test_bayer_uniform_colour(pattern: str, depth: int) -> None:
    scale = 1 if depth == 8 else 256
    mosaic = bayer_mosaic(pattern, 8, 10, (R * scale, G * scale, B * scale))
    dtype = "<u1" if depth == 8 else "<u2"
    data = mosaic.astype(dtype).tobytes()
    out = image_to_numpy(msg(8, 10, f"bayer_{pattern}{depth}", 10 * depth // 8, data))
    assert out.shape == (8, 10, 3) and out.dtype == (np.uint8 if depth == 8 else np.uint16)
    # Interior pixels see full neighbourhoods: the colour must come back exactly.
    np.testing.assert_array_equal(out[2:-2, 2:-2].reshape(-1, 3) // scale,
                                  np.tile([B, G, R], (6 * 4, 1)))


def bt601(y: int, u: int, v: int) -> tuple[float, float, float]:
    """BGR of one video-range BT.601 YUV sample."""
    c, d, e = 1.164 * (y - 16), u - 128, v - 128
    return (c + 2.018 * d, c - 0.391 * d - 0.813 * e, c + 1.596 * e)


@pytest.mark.parametrize(
    ("encoding", "macro"),
    [("yuv422", "uyvy"), ("uyvy", "uyvy"), ("yuv422_yuy2", "yuyv"), ("yuyv", "yuyv")],
)
def test_yuv422_known_samples(encoding: str, macro: str) -> None:
    y0, y1, u, v = 100, 150, 110, 160
    block = bytes([u, y0, v, y1]) if macro == "uyvy" else bytes([y0, u, y1, v])
    grey = bytes([128, 80, 128, 80]) if macro == "uyvy" else bytes([80, 128, 80, 128])
    data = padded([block + grey, grey + block], 10)
    out = image_to_numpy(msg(2, 4, encoding, 10, data))
    assert out.shape == (2, 4, 3) and out.dtype == np.uint8
    np.testing.assert_allclose(out[0, 0], bt601(y0, u, v), atol=2)
    np.testing.assert_allclose(out[0, 1], bt601(y1, u, v), atol=2)
    np.testing.assert_allclose(out[1, 3], bt601(y1, u, v), atol=2)
    grey_value = 1.164 * (80 - 16)
    np.testing.assert_allclose(out[0, 2:].reshape(-1), grey_value, atol=1)


# -- data containers -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "wrap",
    [bytes, bytearray, memoryview, lambda b: array.array("B", b), list,
     lambda b: np.frombuffer(b, np.uint8), lambda b: np.frombuffer(b, np.uint8).reshape(2, -1)],
)
def test_every_data_container(wrap: Any) -> None:
    raw = bytes(range(2 * 6))
    out = image_to_numpy(msg(2, 2, "rgb8", 6, wrap(raw)))
    np.testing.assert_array_equal(out, np.frombuffer(raw, np.uint8).reshape(2, 2, 3)[..., ::-1])


def test_dict_messages_are_accepted() -> None:
    out = image_to_numpy({"height": 1, "width": 2, "encoding": "mono8", "is_bigendian": 0,
                          "step": 2, "data": b"\x07\x09"})
    np.testing.assert_array_equal(out, [[7, 9]])


# -- numpy_to_image --------------------------------------------------------------------------


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_numpy_round_trip_every_encoding(encoding: str) -> None:
    enc = ENCODINGS[encoding]
    rng = np.random.default_rng(3)
    dtype = np.uint8 if enc.depth == 1 else np.uint16
    top = 256 if enc.depth == 1 else 65536
    h, w = 6, 8
    if enc.kind == "mono":
        image = rng.integers(0, top, (h, w), dtype=dtype)
    elif enc.kind == "bayer":
        # a mosaic loses two colours per pixel: 6x6 blocks of uniform colour come back
        # exactly away from the block edges (demosaicing interpolates over 3x3 pixels)
        h, w = 12, 18
        block = rng.integers(0, 256, (2, 3, 3)) * (top // 256)
        image = np.kron(block, np.ones((6, 6, 1))).astype(dtype)
    elif enc.kind in ("uyvy", "yuyv"):
        # U and V are shared by pixel pairs: pairs of equal colour survive (to rounding)
        pairs = rng.integers(40, 200, (h, w // 2, 3))
        image = np.repeat(pairs, 2, axis=1).astype(dtype)
    else:
        image = rng.integers(0, top, (h, w, 3), dtype=dtype)
    fields = numpy_to_image(image, encoding, stamp_ns=1_234_000_000_567, frame_id="cam")
    assert fields["header"] == {"stamp": {"sec": 1234, "nanosec": 567}, "frame_id": "cam"}
    assert (fields["height"], fields["width"], fields["encoding"]) == (h, w, encoding)
    assert fields["step"] == w * enc.bytes_per_pixel
    assert len(fields["data"]) == fields["step"] * h and fields["is_bigendian"] == 0
    back = image_to_numpy(fields)
    assert back.dtype == image.dtype and back.shape == image.shape
    if enc.kind == "bayer":
        inner = np.zeros((h, w), bool)
        for y0 in range(0, h, 6):
            for x0 in range(0, w, 6):
                inner[y0 + 1 : y0 + 5, x0 + 1 : x0 + 5] = True
        np.testing.assert_allclose(back[inner].astype(float), image[inner].astype(float),
                                   atol=top // 256)
    elif enc.kind in ("uyvy", "yuyv"):
        np.testing.assert_allclose(back.astype(float), image.astype(float), atol=3)
    else:
        np.testing.assert_array_equal(back, image)


def test_numpy_to_image_alpha_and_raw_bayer() -> None:
    bgr = np.array([[[B, G, R]]], np.uint8)
    assert numpy_to_image(bgr, "rgba8")["data"] == bytes([R, G, B, 255])
    bgra = np.array([[[B, G, R, 9]]], np.uint8)
    assert numpy_to_image(bgra, "bgra8")["data"] == bytes([B, G, R, 9])
    mosaic = bayer_mosaic("grbg", 4, 4, (R, G, B)).astype(np.uint8)
    assert numpy_to_image(mosaic, "bayer_grbg8")["data"] == mosaic.tobytes()
    sampled = numpy_to_image(np.tile(bgr, (4, 4, 1)), "bayer_grbg8")["data"]
    assert sampled == mosaic.tobytes()


# -- image_to_gray, row padding, byte order --------------------------------------------------


def smooth_bgr(h: int, w: int, depth: int) -> np.ndarray:
    """A BGR image whose colour changes slowly, with channels far apart (swaps show)."""
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    bgr = np.dstack([40 + 60 * x, 120 + 80 * y, 220 - 90 * x * y])
    return (bgr * (1 if depth == 1 else 257)).round().astype(np.uint8 if depth == 1
                                                               else np.uint16)


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_image_to_gray_is_the_grey_of_the_image(encoding: str) -> None:
    enc = ENCODINGS[encoding]
    bgr = smooth_bgr(24, 32, enc.depth)
    truth = to_gray(bgr)
    fields = numpy_to_image(truth if enc.kind == "mono" else bgr, encoding)
    gray = image_to_gray(fields)
    assert gray.shape == (24, 32) and gray.dtype == truth.dtype
    level = 1 if enc.depth == 1 else 257  # one 8-bit grey level
    inner = (slice(2, -2), slice(2, -2))  # demosaicing sees whole neighbourhoods
    if enc.kind == "bayer":
        # the mosaic keeps one colour per pixel; on a smooth image the rest interpolates
        # to within 3 levels, and the colour image comes back as close
        tolerance = 3 * level
        colour = image_to_numpy(fields)
        np.testing.assert_allclose(colour[inner].astype(float), bgr[inner].astype(float),
                                   atol=tolerance)
    elif enc.kind in ("uyvy", "yuyv"):
        tolerance = 1  # the luma, stretched from video range, to rounding
    else:
        tolerance = 0
    np.testing.assert_allclose(gray[inner].astype(float), truth[inner].astype(float),
                               atol=tolerance)
    # the same grey the BGR path gives, whichever path the node takes
    via_bgr = to_gray(image_to_numpy(fields))
    np.testing.assert_allclose(gray[inner].astype(float), via_bgr[inner].astype(float),
                               atol=2 * level if enc.kind == "bayer" else tolerance)
    if enc.depth == 2:
        assert int(gray.max()) > 255  # 16 bits kept, not scaled to 8


def padded_big_endian(fields: dict[str, Any], pad: int, big_endian: bool) -> dict[str, Any]:
    """``fields`` with ``pad`` junk bytes after each row, and 16-bit samples byte-swapped."""
    step = fields["step"]
    rows = np.frombuffer(fields["data"], np.uint8).reshape(fields["height"], step)
    if big_endian:
        rows = rows.reshape(fields["height"], step // 2, 2)[:, :, ::-1].reshape(-1, step)
    junk = np.full((fields["height"], pad), 0xEE, np.uint8)
    return {**fields, "step": step + pad, "is_bigendian": int(big_endian),
            "data": np.hstack([rows, junk]).tobytes()}


@pytest.mark.parametrize("encoding", sorted(ENCODINGS))
def test_row_padding_and_byte_order_change_nothing(encoding: str) -> None:
    enc = ENCODINGS[encoding]
    bgr = smooth_bgr(6, 8, enc.depth)
    plain = numpy_to_image(to_gray(bgr) if enc.kind == "mono" else bgr, encoding)
    orders = [False, True] if enc.depth == 2 else [False]
    for pad in (1, 3, 64):  # odd pads start rows at odd addresses
        for big_endian in orders:
            odd = padded_big_endian(plain, pad, big_endian)
            np.testing.assert_array_equal(image_to_numpy(odd), image_to_numpy(plain))
            np.testing.assert_array_equal(image_to_gray(odd), image_to_gray(plain))


@pytest.mark.parametrize("encoding", ["mono8", "mono16", "16UC1", "bgr8"])
def test_buffer_encodings_are_views_without_a_copy(encoding: str) -> None:
    enc = ENCODINGS[encoding]
    bgr = smooth_bgr(4, 6, enc.depth)
    fields = numpy_to_image(to_gray(bgr) if enc.kind == "mono" else bgr, encoding)
    fields = padded_big_endian(fields, 2 * enc.depth, big_endian=False)
    data = bytearray(fields["data"])
    fields["data"] = data
    buffer = np.frombuffer(data, np.uint8)
    assert np.shares_memory(image_to_numpy(fields), buffer)
    if enc.kind == "mono":
        assert np.shares_memory(image_to_gray(fields), buffer)


# -- errors name the field -------------------------------------------------------------------


def test_errors_name_the_field() -> None:
    with pytest.raises(ImageFormatError,
                       match=r"step 600 < width\*bytes_per_pixel 640 for mono8"):
        image_to_numpy(msg(480, 640, "mono8", 600, bytes(600 * 480)))
    with pytest.raises(ImageFormatError,
                       match=r"data has 1000 bytes, expected step\*height = 307200"):
        image_to_numpy(msg(480, 640, "mono8", 640, bytes(1000)))
    with pytest.raises(ImageFormatError, match=r"data has 307201 bytes"):
        image_to_numpy(msg(480, 640, "mono8", 640, bytes(307201)))
    with pytest.raises(ImageFormatError,
                       match=r"unknown encoding 'foo'; supported: mono8, 8UC1, mono16"):
        image_to_numpy(msg(1, 1, "foo", 1, b"\0"))
    with pytest.raises(ImageFormatError, match=r"step 3 < width\*bytes_per_pixel 4 for mono16"):
        image_to_numpy(msg(1, 2, "mono16", 3, bytes(3)))
    with pytest.raises(ImageFormatError, match="width 3 must be even for yuv422"):
        image_to_numpy(msg(1, 3, "yuv422", 6, bytes(6)))
    with pytest.raises(ImageFormatError, match="the image is empty"):
        image_to_numpy(msg(0, 4, "mono8", 4, b""))
    with pytest.raises(ImageFormatError, match="height must be >= 0"):
        image_to_numpy(msg(-1, 4, "mono8", 4, b""))
    with pytest.raises(ImageFormatError, match="width must be an integer"):
        image_to_numpy(msg(1, "wide", "mono8", 4, b""))  # type: ignore[arg-type]
    with pytest.raises(ImageFormatError, match="no field 'step'"):
        image_to_numpy(SimpleNamespace(height=1, width=1, encoding="mono8", is_bigendian=0,
                                       data=b"\0"))
    with pytest.raises(ImageFormatError, match="data is not a sequence of bytes"):
        image_to_numpy(msg(1, 1, "mono8", 1, [300]))
    with pytest.raises(ImageFormatError, match="mono16 needs a uint16 array, got uint8"):
        numpy_to_image(np.zeros((2, 2), np.uint8), "mono16")
    with pytest.raises(ImageFormatError, match=r"bgr8 needs an \(H, W, 3\) BGR array"):
        numpy_to_image(np.zeros((2, 2), np.uint8), "bgr8")
    with pytest.raises(ImageFormatError, match=r"mono8 needs an \(H, W\) array"):
        numpy_to_image(np.zeros((2, 2, 3), np.uint8), "mono8")


# -- compressed ------------------------------------------------------------------------------


def encoded(ext: str, image: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(ext, image)
    assert ok
    return buf.tobytes()


# (format string as drivers write it, codec, what the camera sent, channel order compressed)
DRIVER_FORMATS = [
    # image_transport (ROS 2): jpeg converts colour to bgr8 first, png keeps the depth
    ("bgr8; jpeg compressed bgr8", ".jpg", "bgr8", "bgr"),
    ("rgb8; jpeg compressed bgr8", ".jpg", "bgr8", "bgr"),
    ("mono8; jpeg compressed mono8", ".jpg", "mono8", "mono"),
    ("bgr8; png compressed bgr8", ".png", "bgr8", "bgr"),
    ("bgr16; png compressed bgr16", ".png", "bgr16", "bgr"),
    ("mono8; png compressed mono8", ".png", "mono8", "mono"),
    ("mono16; png compressed mono16", ".png", "mono16", "mono"),
    ("16UC1; png compressed 16UC1", ".png", "mono16", "mono"),
    # a colour camera's grey stream, compressed in colour
    ("mono8; jpeg compressed bgr8", ".jpg", "mono8", "bgr"),
    # older drivers and ROS 1's image_transport: the codec alone, or rgb pixels kept as rgb
    ("jpeg", ".jpg", "bgr8", "bgr"),
    ("jpeg", ".jpg", "mono8", "mono"),
    ("png", ".png", "bgr8", "bgr"),
    ("png", ".png", "mono16", "mono"),
    ("rgb8; png compressed rgb8", ".png", "bgr8", "rgb"),
    ("rgb8; jpeg compressed rgb8", ".jpg", "bgr8", "rgb"),
]


@pytest.mark.parametrize(("fmt", "ext", "sent", "order"), DRIVER_FORMATS)
def test_compressed_driver_formats(fmt: str, ext: str, sent: str, order: str) -> None:
    depth = 2 if sent.endswith("16") else 1
    bgr = smooth_bgr(24, 40, depth)
    grey = to_gray(bgr)
    pixels = {"bgr": bgr, "rgb": bgr[:, :, ::-1], "mono": grey}[order]
    if order != "mono" and sent.startswith("mono"):
        pixels = cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)
    frame = SimpleNamespace(format=fmt, data=array.array("B", encoded(ext, pixels)))
    image = compressed_to_numpy(frame)
    gray = compressed_to_gray(frame)
    expected = grey if sent.startswith("mono") else bgr
    assert image.shape == expected.shape and image.dtype == expected.dtype
    assert gray.shape == grey.shape and gray.dtype == grey.dtype
    if ext == ".png":  # lossless, 16 bits included
        np.testing.assert_array_equal(image, expected)
        np.testing.assert_array_equal(gray, grey)
    else:  # jpeg on a smooth image: luma within 3 levels, chroma (subsampled) within 6;
        # swapped channels would be 100 off
        np.testing.assert_allclose(image.astype(float), expected.astype(float), atol=6)
        np.testing.assert_allclose(gray.astype(float), grey.astype(float), atol=3)
    # the same grey the colour path gives
    np.testing.assert_allclose(gray.astype(float), to_gray(image).astype(float), atol=1)


def test_compressed_errors() -> None:
    with pytest.raises(ImageFormatError, match="format 'theora' is not supported"):
        compressed_to_numpy(SimpleNamespace(format="theora", data=b"xx"))
    with pytest.raises(ImageFormatError, match=r"data does not start like a PNG or JPEG file"):
        compressed_to_numpy(SimpleNamespace(format="jpeg", data=b"hello"))
    with pytest.raises(ImageFormatError, match="no field 'format'"):
        compressed_to_numpy(SimpleNamespace(data=b""))


# -- to_gray ---------------------------------------------------------------------------------


def test_to_gray() -> None:
    bgr = np.zeros((2, 2, 3), np.uint8)
    bgr[0, 0] = (255, 0, 0)  # pure blue: 0.114 of full scale
    bgr[0, 1] = (0, 0, 255)  # pure red: 0.299
    gray = to_gray(bgr)
    assert gray.shape == (2, 2) and gray.dtype == np.uint8
    assert (gray[0, 0], gray[0, 1]) == (29, 76)
    g16 = to_gray(bgr.astype(np.uint16) * 257)
    assert g16.dtype == np.uint16 and abs(int(g16[0, 1]) - 76 * 257) < 257
    mono = np.arange(6, dtype=np.uint16).reshape(2, 3)
    assert to_gray(mono) is mono
    assert to_gray(mono[:, :, None]).shape == (2, 3)
    assert to_gray(np.dstack([bgr, np.zeros((2, 2), np.uint8)]))[0, 1] == 76
    with pytest.raises(ImageFormatError, match=r"shape \(2, 2, 2\)"):
        to_gray(np.zeros((2, 2, 2), np.uint8))


# -- real ROS messages -----------------------------------------------------------------------


def test_real_sensor_msgs_image() -> None:
    sensor_msgs = pytest.importorskip("sensor_msgs.msg")
    rng = np.random.default_rng(9)
    cases: list[tuple[str, np.ndarray]] = [
        ("mono8", rng.integers(0, 256, (5, 7), dtype=np.uint8)),
        ("mono16", rng.integers(0, 65536, (5, 7), dtype=np.uint16)),
        ("rgb8", rng.integers(0, 256, (5, 7, 3), dtype=np.uint8)),
    ]
    for encoding, image in cases:
        fields = numpy_to_image(image, encoding, stamp_ns=5_000_000_001, frame_id="cam")
        m = sensor_msgs.Image()
        for key, value in fields.items():
            if key != "header":
                setattr(m, key, value)
        m.header.frame_id = fields["header"]["frame_id"]
        m.header.stamp.sec = fields["header"]["stamp"]["sec"]
        m.header.stamp.nanosec = fields["header"]["stamp"]["nanosec"]
        assert isinstance(m.data, array.array)  # rclpy's own container
        np.testing.assert_array_equal(image_to_numpy(m), image)
    c = sensor_msgs.CompressedImage()
    c.format = "png"
    c.data = encoded(".png", np.full((3, 4), 42, np.uint8))
    np.testing.assert_array_equal(compressed_to_numpy(c), np.full((3, 4), 42))
