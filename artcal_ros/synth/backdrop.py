"""The scene behind the board: a cluttered wall, seen through the same lens model.

The wall is a plane parallel to the board, ``distance_m`` behind it, papered
with a random clutter texture (mirrored without end). Each pixel's viewing ray
(the camera's exact inverse model) is intersected with it, so the background
moves with the camera as it should in a hand-held sweep, is distorted by the
lens like everything else, and stays the same room from view to view. Rays that
never reach the wall see its mean colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.photometry import clutter_image


@dataclass(frozen=True, eq=False)
class Backdrop:
    """A textured wall parallel to the board.

    Attributes:
        texture: (Ht, Wt, 3) float32 linear RGB reflectance.
        origin_m: board-frame (x, y) of the texture's pixel (0, 0) centre, metres.
        px_per_m: texture pixels per metre on the wall.
        distance_m: the wall lies in the board-frame plane z = +distance_m (behind the board).
    """

    texture: np.ndarray
    origin_m: tuple[float, float]
    px_per_m: float
    distance_m: float

    @classmethod
    def random(cls, board: Board, rng: np.random.Generator, *, distance_m: float = 1.5,
               extent_m: tuple[float, float] = (9.0, 6.0), px_per_m: float = 160.0) -> Backdrop:
        """A random cluttered wall centred behind the board."""
        w = round(extent_m[0] * px_per_m)
        h = round(extent_m[1] * px_per_m)
        texture = clutter_image((w, h), rng).astype(np.float32)
        bw, bh = board.size_m
        origin = (bw / 2 - extent_m[0] / 2, bh / 2 - extent_m[1] / 2)
        return cls(texture=texture, origin_m=origin, px_per_m=px_per_m, distance_m=distance_m)

    def render(self, cam: Camera, rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
        """(H, W, 3) float32 linear reflectance of the wall seen by every pixel."""
        R = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64).reshape(3, 1))[0]
        t = np.asarray(tvec, dtype=np.float64).reshape(3)
        ray, _, _, valid = cam.pixel_rays()
        w, h = cam.size
        # the wall is out of focus and smooth: map it on a coarse grid, interpolate the map
        step = 4
        ray, valid = ray[::step, ::step], valid[::step, ::step]
        gh, gw = valid.shape
        C = -R.T @ t                       # camera centre in the board frame
        d = ray.reshape(-1, 3) @ R         # ray directions in the board frame (R^T ray)
        with np.errstate(divide="ignore", invalid="ignore"):
            lam = (self.distance_m - C[2]) / d[:, 2]
        hit = valid.ravel() & (lam > 0) & np.isfinite(lam)
        lam = np.where(hit, lam, 0.0)
        mx = (C[0] + lam * d[:, 0] - self.origin_m[0]) * self.px_per_m
        my = (C[1] + lam * d[:, 1] - self.origin_m[1]) * self.px_per_m
        tex_h, tex_w = self.texture.shape[:2]
        # the wall mirrored a few times over; beyond that (grazing rays, misses) its mean
        far = ~hit | (np.abs(mx) > 4 * tex_w) | (np.abs(my) > 4 * tex_h)
        mx = np.where(far, 0.0, mx).astype(np.float32).reshape(gh, gw)
        my = np.where(far, 0.0, my).astype(np.float32).reshape(gh, gw)
        # where one pixel spans many texels (grazing views) the texture would alias: fade it
        # to its mean colour, as an out-of-focus, far-away wall would look
        along_x = np.hypot(np.gradient(mx, axis=1), np.gradient(my, axis=1))
        along_y = np.hypot(np.gradient(mx, axis=0), np.gradient(my, axis=0))
        texels = np.maximum(along_x, along_y) / step    # texels per image pixel
        fade = np.clip((texels - 2.0) / 6.0, 0.0, 1.0).astype(np.float32)
        fade[far.reshape(gh, gw)] = 1.0
        # grid point (i, j) is pixel (step * j, step * i): an affine warp to the full image
        to_full = np.array([[1.0 / step, 0, 0], [0, 1.0 / step, 0]], dtype=np.float64)
        mx, my, fade = (cv2.warpAffine(a, to_full, (w, h), flags=cv2.INTER_LINEAR
                                       | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
                        for a in (mx, my, fade))
        mean = self.texture.reshape(-1, 3).mean(axis=0).astype(np.float32)
        out = cv2.remap(self.texture, mx, my, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REFLECT_101)
        wall: np.ndarray = np.asarray(out, dtype=np.float32)
        return np.asarray(wall + fade[..., None] * (mean - wall), dtype=np.float32)
