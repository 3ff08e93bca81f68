"""Light and sensor model of the renderer: from exact coverage to an encoded image.

Everything up to the sensor happens in linear light, in this order:

1. radiance = illumination x reflectance. The board's paper and ink reflect
   ``paper`` and ``ink``; its illumination falls off linearly across the board
   (``gradient``, random direction per view); a cluttered background fills the
   rest of the image;
2. optics: defocus (a disc of radius ``defocus_px``) and motion blur (a line of
   ``motion_px``), both symmetric so they widen edges without moving them;
   then vignetting (``vignetting``: fractional loss at the image corner);
3. sensor: ``exposure`` scales radiance to full scale (1.0), shot noise for a
   ``full_well`` of electrons plus Gaussian ``read_noise`` electrons, clipping
   at full scale (saturation);
4. encoding: ``gamma`` (out = in ** (1 / gamma); 1.0 keeps the output linear),
   quantisation to 8 or 16 bits, optional JPEG round trip.

In gamma-encoded output an edge's grey midpoint is *not* where the edge is: the
encoding is non-linear, so the 50 % crossing of a blurred edge moves towards
the dark side. Use :meth:`Photometry.exact` (linear, noise-free, unit
contrast) to measure edge positions against the truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from artcal_ros.core.errors import ParameterError

ENCODINGS = ("mono8", "mono16", "bgr8", "rgb8")


@dataclass(frozen=True)
class Photometry:
    """Illumination, optics, sensor and encoding settings (see the module docstring).

    Attributes:
        paper, ink: reflectance of the board's white and black print, 0..1.
        illumination: irradiance on the board relative to full scale at exposure 1.
        gradient: relative illumination change from the board's centre to its corner.
        background: irradiance on the background clutter (relative, like ``illumination``).
        clutter: draw a cluttered background; False leaves it uniformly dark grey.
        vignetting: fractional brightness loss at the image corners (0 = none).
        defocus_px: defocus disc radius, pixels (0 = sharp).
        motion_px: motion blur length, pixels; ``motion_angle_deg`` None picks one per view.
        exposure: radiance -> fraction of sensor full scale; above 1/paper the paper saturates.
        noise: add shot and read noise.
        full_well: electrons at full scale (shot noise: sqrt(electrons)).
        read_noise: read noise, electrons rms.
        gamma: encoding exponent, out = in ** (1 / gamma); 1.0 = linear output.
        srgb: encode with the sRGB curve (IEC 61966-2-1) instead (``gamma`` unused).
        jpeg_quality: JPEG round trip at this quality (8-bit encodings only), None = off.
        tint: linear RGB gains of the light for colour encodings (mono uses their mean 1).
    """

    paper: float = 0.8
    ink: float = 0.05
    illumination: float = 1.0
    gradient: float = 0.12
    background: float = 0.8
    clutter: bool = True
    vignetting: float = 0.15
    defocus_px: float = 0.0
    motion_px: float = 0.0
    motion_angle_deg: float | None = None
    exposure: float = 1.0
    noise: bool = True
    full_well: float = 10000.0
    read_noise: float = 3.0
    gamma: float = 2.2
    srgb: bool = False
    jpeg_quality: int | None = None
    tint: tuple[float, float, float] = (1.05, 1.0, 0.92)

    def __post_init__(self) -> None:
        checks = {
            "paper": 0 <= self.paper <= 1, "ink": 0 <= self.ink <= 1,
            "illumination": self.illumination >= 0, "gradient": 0 <= self.gradient < 1,
            "background": self.background >= 0, "vignetting": 0 <= self.vignetting < 1,
            "defocus_px": 0 <= self.defocus_px <= 50, "motion_px": 0 <= self.motion_px <= 100,
            "exposure": self.exposure > 0, "full_well": self.full_well > 0,
            "read_noise": self.read_noise >= 0, "gamma": self.gamma > 0,
            "jpeg_quality": self.jpeg_quality is None or 1 <= self.jpeg_quality <= 100,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise ParameterError(f"photometry: bad value for {', '.join(bad)} "
                                 f"({', '.join(f'{k}={getattr(self, k)!r}' for k in bad)})")

    @classmethod
    def clean(cls) -> Photometry:
        """A well-lit, focused, lightly noisy view (the default)."""
        return cls()

    @classmethod
    def harsh(cls) -> Photometry:
        """Uneven light, overexposure, defocus, motion blur, strong noise and JPEG."""
        return cls(gradient=0.5, vignetting=0.4, defocus_px=1.2, motion_px=2.5,
                   exposure=1.35, full_well=1500.0, read_noise=12.0, jpeg_quality=70,
                   background=1.1)

    @classmethod
    def exact(cls) -> Photometry:
        """Linear, noise-free, unit-contrast output: pixel = white area fraction.

        With this, an image value of 0.5 (of full scale) is exactly on an edge, and the
        row sum across an edge gives its position (see the tests)."""
        return cls(paper=1.0, ink=0.0, gradient=0.0, clutter=False, background=0.0,
                   vignetting=0.0, noise=False, gamma=1.0, tint=(1.0, 1.0, 1.0))

    @classmethod
    def by_name(cls, name: str) -> Photometry:
        """``clean``, ``harsh`` or ``exact``."""
        makers = {"clean": cls.clean, "harsh": cls.harsh, "exact": cls.exact}
        if name not in makers:
            raise ParameterError(f"unknown photometry {name!r}; use one of {', '.join(makers)}")
        return makers[name]()

    def with_(self, **changes: object) -> Photometry:
        """A copy with some fields changed."""
        return replace(self, **changes)  # type: ignore[arg-type]


def clutter_image(size: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A random cluttered background: (H, W, 3) float32 linear RGB reflectance, ~0.0002-1.

    Smooth shading, rectangles, ellipses, lines and dark/light patches, some with sharp
    square corners (to tempt a marker detector), all in colour."""
    w, h = size
    base = (255 * rng.uniform(0.05, 0.5, size=(4, 6, 3))).astype(np.uint8)
    # smooth shading: cubic to a coarse grid, then (fast) bilinear to full size
    coarse = cv2.resize(base, (48, 27), interpolation=cv2.INTER_CUBIC)
    img8 = cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR)
    scale = max(w, h)
    # about 30 shapes per 640 x 480 of picture
    count = min(int(rng.integers(20, 45) * max(1.0, w * h / (640 * 480))), 300)
    for _ in range(count):
        grey = rng.uniform(10, 230)   # mostly muted colours, like a room
        color = tuple(int(grey + 0.45 * (c - grey)) for c in rng.uniform(5, 235, size=3))
        kind = rng.integers(0, 4)
        cx, cy = rng.uniform(0, w), rng.uniform(0, h)
        s = rng.uniform(0.015, 0.15) * scale
        if kind == 0:      # rotated rectangle
            box = cv2.boxPoints(((cx, cy), (s, s * rng.uniform(0.2, 1.5)), rng.uniform(0, 180)))
            cv2.fillPoly(img8, [np.round(box * 16).astype(np.int32)], color, cv2.LINE_AA, 4)
        elif kind == 1:    # ellipse
            cv2.ellipse(img8, ((cx, cy), (s, s * rng.uniform(0.3, 1.0)), rng.uniform(0, 180)),
                        color, -1, cv2.LINE_AA)
        elif kind == 2:    # line
            ang = rng.uniform(0, 2 * math.pi)
            p0 = (int(cx), int(cy))
            p1 = (int(cx + s * math.cos(ang)), int(cy + s * math.sin(ang)))
            cv2.line(img8, p0, p1, color, int(rng.integers(1, 6)), cv2.LINE_AA)
        else:              # dark square with a light frame: a marker-like distractor
            q = s * 0.5
            cv2.rectangle(img8, (int(cx - q), int(cy - q)), (int(cx + q), int(cy + q)),
                          (30, 30, 30), -1)
            cv2.rectangle(img8, (int(cx - q), int(cy - q)), (int(cx + q), int(cy + q)),
                          (220, 220, 220), max(1, int(q * 0.15)))
    # drawn in gamma-encoded 8-bit; to linear light through a table, then a fine grain
    lut = (np.clip(np.arange(256) / 255.0, 0.02, 0.9) ** 2.2).astype(np.float32)
    lin = lut[img8]
    grain = rng.standard_normal((h, w), dtype=np.float32)
    lin *= (1.0 + 0.08 * grain)[..., None]
    return np.asarray(lin)


def _disc_kernel(radius: float) -> np.ndarray:
    """Normalised disc (defocus PSF) of ``radius`` px, area-sampled, odd size."""
    r = math.ceil(radius) + 1
    sub = 8
    g = (np.arange(-r * sub, (r + 1) * sub) + 0.5) / sub - 0.5
    xx, yy = np.meshgrid(g, g)
    inside = (xx * xx + yy * yy <= radius * radius).astype(np.float64)
    k = inside.reshape(2 * r + 1, sub, 2 * r + 1, sub).mean(axis=(1, 3))
    k = 0.5 * (k + k[::-1, ::-1])   # exactly point-symmetric: blur must not move edges
    if not k.sum() > 0:              # a disc smaller than the sampling: no blur
        return np.ones((1, 1))
    return np.asarray(k / k.sum())


def _line_kernel(length: float, angle_deg: float) -> np.ndarray:
    """Normalised, point-symmetric motion-blur line of ``length`` px at ``angle_deg``."""
    r = math.ceil(length / 2) + 1
    k: np.ndarray = np.zeros((2 * r + 1, 2 * r + 1))
    a = math.radians(angle_deg)
    for t in np.linspace(-length / 2, length / 2, max(int(length * 8), 2)):
        x, y = r + t * math.cos(a), r + t * math.sin(a)
        x0, y0 = math.floor(x), math.floor(y)
        fx, fy = x - x0, y - y0
        for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)),
                            (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
            k[y0 + dy, x0 + dx] += wgt
    k = 0.5 * (k + k[::-1, ::-1])
    return k / k.sum()


def blur(lin: np.ndarray, phot: Photometry, rng: np.random.Generator) -> np.ndarray:
    """Defocus and motion blur of a linear image (H, W) or (H, W, C), in linear light."""
    out = lin
    if phot.defocus_px >= 0.2:
        out = cv2.filter2D(out, -1, _disc_kernel(phot.defocus_px),
                           borderType=cv2.BORDER_REFLECT)
    if phot.motion_px >= 0.2:
        angle = (phot.motion_angle_deg if phot.motion_angle_deg is not None
                 else float(rng.uniform(0, 180)))
        out = cv2.filter2D(out, -1, _line_kernel(phot.motion_px, angle),
                           borderType=cv2.BORDER_REFLECT)
    return out


def vignette(size: tuple[int, int], strength: float) -> np.ndarray:
    """(H, W) relative brightness: 1 at the centre, 1 - strength at the corners (cos^4-like)."""
    w, h = size
    u = (np.arange(w) - (w - 1) / 2) / ((w - 1) / 2)
    v = (np.arange(h) - (h - 1) / 2) / ((h - 1) / 2)
    r2 = (u[None, :] ** 2 + v[:, None] ** 2) / 2.0
    return np.asarray(1.0 - strength * r2 * (0.6 + 0.4 * r2))


def sense_and_encode(radiance: np.ndarray, phot: Photometry, rng: np.random.Generator,
                     encoding: str) -> np.ndarray:
    """Sensor (exposure, noise, saturation) and encoding of a linear image.

    Args:
        radiance: (H, W) or (H, W, 3) float64 linear radiance after optics (RGB order).
        encoding: ``mono8``, ``mono16``, ``bgr8`` or ``rgb8``.

    Returns:
        (H, W) uint8 / uint16, or (H, W, 3) uint8 in OpenCV's BGR order for both colour
        encodings (as :func:`artcal_ros.core.images.image_to_numpy` returns them; the
        encoding decides the channel order only in a message).
    """
    signal = radiance * phot.exposure
    if phot.noise:
        electrons = np.maximum(signal, 0.0) * phot.full_well
        # shot noise (Gaussian approximation of Poisson, fine above a few electrons) + read
        electrons = electrons + rng.standard_normal(signal.shape) * np.sqrt(
            electrons + phot.read_noise ** 2)
        signal = electrons / phot.full_well
    signal = np.minimum(np.maximum(signal, 0.0), 1.0)
    if phot.srgb:
        signal = np.where(signal <= 0.0031308, 12.92 * signal,
                          1.055 * signal ** (1.0 / 2.4) - 0.055)
    elif phot.gamma != 1.0:
        signal = signal ** (1.0 / phot.gamma)
    if encoding == "mono16":
        return np.round(signal * 65535.0).astype(np.uint16)
    out = np.round(signal * 255.0).astype(np.uint8)
    if out.ndim == 3:
        out = np.ascontiguousarray(out[..., ::-1])   # RGB -> BGR
    if phot.jpeg_quality is not None:
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(phot.jpeg_quality)])
        if ok:
            flag = cv2.IMREAD_GRAYSCALE if out.ndim == 2 else cv2.IMREAD_COLOR
            decoded = cv2.imdecode(buf, flag)
            if decoded is not None:
                out = np.asarray(decoded, dtype=np.uint8)
    return out
