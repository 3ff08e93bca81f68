"""The input image in the two forms detection reads: 8-bit grey for the quad finder, linear light.

A pixel integrates light and the gamma encoding comes afterwards, so every
sub-pixel measurement (edges, cell reads) is made in linear intensity; only
OpenCV's quad finder sees the encoded, contrast-stretched 8-bit copy.
"""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.errors import DetectionError


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8/uint16 from (H, W), (H, W, 1), (H, W, 3) BGR or (H, W, 4) BGRA.

    Raises:
        DetectionError: for any other shape, or a dtype other than uint8/uint16.
    """
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        img = cv2.cvtColor(img, code)
    if img.ndim != 2:
        raise DetectionError(f"expected an (H, W) or (H, W, 3) image, got shape {img.shape}")
    if img.dtype not in (np.uint8, np.uint16):
        raise DetectionError(f"expected a uint8 or uint16 image, got {img.dtype}; "
                             "convert it (e.g. scale floats to 0..255 and cast to uint8)")
    return img


def to_gray8(gray: np.ndarray) -> np.ndarray:
    """An 8-bit copy for the quad finder, contrast-stretched so dark frames still threshold.

    The stretch maps the 0.5th..99.5th percentile to 0..255 when that range is narrow.

    Args:
        gray: (H, W) uint8 or uint16 grey image.

    Returns:
        (H, W) uint8.
    """
    g = gray
    if g.dtype == np.uint16:
        hi = float(np.percentile(g[::4, ::4], 99.9))
        g = np.clip(g.astype(np.float32) * (255.0 / max(hi, 1.0)), 0, 255).astype(np.uint8)
    lo, hi = np.percentile(g[::4, ::4], (0.5, 99.5))
    if hi - lo < 120 and hi > lo:
        scale = 230.0 / (hi - lo)
        g = np.clip((g.astype(np.float32) - lo) * scale + 12.0, 0, 255).astype(np.uint8)
    return g


def linearise(gray: np.ndarray, gamma: float) -> np.ndarray:
    """(H, W) float32 linear intensity in 0..1 from encoded grey values.

    Args:
        gray: (H, W) uint8 or uint16 grey image.
        gamma: ``linear = (v / full_scale) ** gamma``.
    """
    if gray.dtype == np.uint8:
        lut = ((np.arange(256) / 255.0) ** gamma).astype(np.float32)
        return lut[gray]
    if gamma == 1.0:
        return gray.astype(np.float32) * np.float32(1.0 / 65535.0)
    lut = ((np.arange(65536) / 65535.0) ** gamma).astype(np.float32)
    return lut[gray]


def sharpness(gray8: np.ndarray) -> float:
    """A focus measure: the variance of the 8-bit image's Laplacian (larger is sharper).

    Args:
        gray8: (H, W) uint8 image.
    """
    # an integer Laplacian, its sums in double: a fraction of a float image's .var() time
    lap = cv2.Laplacian(gray8, cv2.CV_16S)
    n = max(lap.size, 1)
    total = float(np.asarray(cv2.sumElems(lap), dtype=np.float64)[0])
    return float(cv2.norm(lap, cv2.NORM_L2SQR) / n - (total / n) ** 2)
