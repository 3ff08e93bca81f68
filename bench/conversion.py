"""Image message conversion per frame at 1920x1080, for every encoding a camera driver sends.

    python -m bench.conversion            # 30 timed repeats per encoding
    python -m bench.conversion --quick    # 5 repeats

One rendered 1920x1080 calibration frame (the board before a cluttered wall, the
renderer's clean photometry, in colour) is packed into each encoding as a driver would
send it, the data an ``array.array`` as rclpy hands it over, and compressed as
image_transport does (jpeg quality 95, png level 3). Per encoding, the median
milliseconds per frame of:

- ``to image``: :func:`image_to_numpy` / :func:`compressed_to_numpy`, the (H, W) grey or
  (H, W, 3) BGR array the node overlays;
- ``to grey``: :func:`image_to_gray` / :func:`compressed_to_gray`, the grey the detector
  reads, made straight from the message;
- ``grey via image``: ``to_gray`` of the array ``to image`` gives, the two-step path the
  one-pass one replaces (a reference measured in the same run);
- ``copy``: one copy of the message's bytes, the floor any conversion that touches every
  byte stands on.

``grey RMS error`` is the RMS difference, in 8-bit grey levels, between ``to grey`` and
the grey of the rendered frame (away from the border, where demosaicing sees half a
window): 0 for lossless encodings; a bayer mosaic and jpeg lose detail at the board's
sharp edges, yuv422 rounds.
The load averages before and after the run are printed: times on a busy machine are
longer, and the ratios within one run are what to compare.
"""

from __future__ import annotations

import argparse
import array
import os
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.images import (
    image_to_gray,
    image_to_numpy,
    numpy_to_image,
    to_gray,
)
from artcal_ros.core.images.compressed import compressed_to_gray, compressed_to_numpy
from artcal_ros.synth import Camera, render_view
from artcal_ros.synth.backdrop import Backdrop
from artcal_ros.synth.poses import smooth_poses

# sensor_msgs/Image encodings, in the order; uyvy and yuyv are the same layouts as
# yuv422 and yuv422_yuy2 under other names.
RAW_ENCODINGS = [
    "mono8", "mono16", "16UC1", "rgb8", "bgr8", "rgba8", "bgra8", "yuv422", "yuv422_yuy2",
    "bayer_rggb8", "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8",
    "bayer_rggb16", "bayer_bggr16", "bayer_gbrg16", "bayer_grbg16",
]
# CompressedImage format strings as image_transport writes them
COMPRESSED_FORMATS = [
    "bgr8; jpeg compressed bgr8", "mono8; jpeg compressed mono8",
    "bgr8; png compressed bgr8", "mono16; png compressed mono16",
]
ENCODE_PARAMS = {"jpeg": [cv2.IMWRITE_JPEG_QUALITY, 95], "png": [cv2.IMWRITE_PNG_COMPRESSION, 3]}
BORDER_PX = 4  # left out of the grey error: demosaicing at the border sees half a window


@dataclass(frozen=True)
class Row:
    """Median milliseconds per frame of one encoding's conversions, and its size.

    Attributes:
        encoding: the Image encoding or the CompressedImage format string.
        mb: the message's data, megabytes (1e6 bytes) per frame.
        image_ms, gray_ms, gray_via_image_ms, copy_ms: see the module's description.
        gray_rms: RMS of (to grey - grey of the frame), 8-bit grey levels.
    """

    encoding: str
    mb: float
    image_ms: float
    gray_ms: float
    gray_via_image_ms: float
    copy_ms: float
    gray_rms: float


def rendered_frame(seed: int = 7) -> np.ndarray:
    """(1080, 1920, 3) uint8 BGR: a calibration view of the default board, rendered."""
    board = Board()
    cam = Camera.preset("hd")
    rng = np.random.default_rng(seed)
    wall = Backdrop.random(board, np.random.default_rng([seed, 2]))
    rvec, tvec = smooth_poses(board, cam, 1, rng)[0]
    return render_view(board, cam, rvec, tvec, rng=rng, backdrop=wall, encoding="bgr8").image


def camera_pixels(bgr: np.ndarray, *, sixteen: bool, mono: bool) -> np.ndarray:
    """What a camera would put in the message: ``bgr`` (H, W, 3) uint8 widened to 16 bits
    (x 257) and made grey, as asked."""
    pixels = bgr.astype(np.uint16) * 257 if sixteen else bgr
    return to_gray(pixels) if mono else pixels


def raw_message(bgr: np.ndarray, encoding: str) -> SimpleNamespace:
    """``bgr`` (H, W, 3) uint8 as a sensor_msgs/Image-like message in ``encoding``."""
    pixels = camera_pixels(bgr, sixteen=encoding.endswith("16") or encoding == "16UC1",
                           mono=encoding.startswith(("mono", "16UC1")))
    fields = numpy_to_image(pixels, encoding)
    return SimpleNamespace(**{**fields, "data": array.array("B", fields["data"])})


def compressed_message(bgr: np.ndarray, fmt: str) -> SimpleNamespace:
    """``bgr`` (H, W, 3) uint8 as a sensor_msgs/CompressedImage-like message."""
    codec = "jpeg" if "jpeg" in fmt else "png"
    original = fmt.split(";")[0]
    pixels = camera_pixels(bgr, sixteen=original.endswith("16"),
                           mono=original.startswith("mono"))
    ok, data = cv2.imencode("." + codec.replace("jpeg", "jpg"), pixels, ENCODE_PARAMS[codec])
    if not ok:
        raise RuntimeError(f"OpenCV could not encode {fmt}")
    return SimpleNamespace(format=fmt, data=array.array("B", data.tobytes()))


def median_ms(calls: list[Callable[[], Any]], repeats: int) -> list[float]:
    """Median wall milliseconds of each call over ``repeats`` rounds, after one warm-up.

    The calls take turns within each round, so a burst of load from other processes
    lengthens all of them alike and their ratios hold.
    """
    times: list[list[float]] = [[] for _ in calls]
    for call in calls:
        call()
    for _ in range(repeats):
        for call, spent in zip(calls, times, strict=True):
            start = time.perf_counter()
            call()
            spent.append(time.perf_counter() - start)
    return [1e3 * statistics.median(spent) for spent in times]


def gray_rms(gray: np.ndarray, bgr: np.ndarray) -> float:
    """RMS difference, 8-bit grey levels, between ``gray`` (H, W) uint8/uint16 and the
    grey of ``bgr`` (H, W, 3) uint8 at the same depth, away from the border."""
    sixteen = gray.dtype == np.uint16
    truth = to_gray(bgr.astype(np.uint16) * 257 if sixteen else bgr)
    inner = (slice(BORDER_PX, -BORDER_PX), slice(BORDER_PX, -BORDER_PX))
    diff = gray[inner].astype(np.float64) - truth[inner].astype(np.float64)
    return float(np.sqrt(np.mean(diff**2))) / (257.0 if sixteen else 1.0)


def _gray_via(to_image: Callable[[Any], np.ndarray], msg: Any) -> np.ndarray:
    return to_gray(to_image(msg))


def run(bgr: np.ndarray, repeats: int, encodings: list[str] | None = None,
        formats: list[str] | None = None) -> list[Row]:
    """Time every conversion of ``bgr`` (H, W, 3) uint8, with even W; rows in the order
    of ``encodings`` (default :data:`RAW_ENCODINGS`), then ``formats`` (default
    :data:`COMPRESSED_FORMATS`)."""
    rows = []
    cases: list[tuple[str, SimpleNamespace, Callable[[Any], np.ndarray],
                      Callable[[Any], np.ndarray]]] = []
    for encoding in RAW_ENCODINGS if encodings is None else encodings:
        cases.append((encoding, raw_message(bgr, encoding), image_to_numpy, image_to_gray))
    for fmt in COMPRESSED_FORMATS if formats is None else formats:
        cases.append((fmt, compressed_message(bgr, fmt), compressed_to_numpy,
                      compressed_to_gray))
    for name, msg, to_image, to_grey in cases:
        image_ms, gray_ms, via_ms, copy_ms = median_ms([
            partial(to_image, msg), partial(to_grey, msg), partial(_gray_via, to_image, msg),
            partial(np.array, msg.data, np.uint8)], repeats)
        rows.append(Row(encoding=name, mb=len(msg.data) / 1e6, image_ms=image_ms,
                        gray_ms=gray_ms, gray_via_image_ms=via_ms, copy_ms=copy_ms,
                        gray_rms=gray_rms(to_grey(msg), bgr)))
    return rows


def table(rows: list[Row]) -> str:
    """A markdown table of the rows."""
    lines = ["| encoding | MB/frame | to image ms | to grey ms | grey via image ms | copy ms "
             "| grey RMS error (levels) |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| `{r.encoding}` | {r.mb:.2f} | {r.image_ms:.2f} | {r.gray_ms:.2f} "
                     f"| {r.gray_via_image_ms:.2f} | {r.copy_ms:.2f} | {r.gray_rms:.2f} |")
    return "\n".join(lines)


def load_text() -> str:
    """The 1, 5 and 15 minute load averages and the cores, as ``uptime`` gives them."""
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f}, {five:.2f}, {fifteen:.2f} on {os.cpu_count()} cores"


def main(argv: list[str] | None = None) -> int:
    """Render the frame, time every conversion, print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="5 timed repeats instead of 30")
    ap.add_argument("--repeats", type=int, default=None, help="timed repeats per conversion")
    args = ap.parse_args(argv)
    repeats = args.repeats or (5 if args.quick else 30)
    bgr = rendered_frame()
    print(f"1920x1080, median of {repeats} per conversion, OpenCV {cv2.__version__} with "
          f"{cv2.getNumThreads()} threads; before: {load_text()}", flush=True)
    rows = run(bgr, repeats)
    print(table(rows))
    print(f"after: {load_text()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
