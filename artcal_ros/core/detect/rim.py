"""Markers the lens bends too much to read by a homography, read again through the lens.

Far out in a strong lens (the rim of a fisheye) a marker's sides bow by a large part of a
module: the quad finder still closes a contour around it, but the code cells a homography
of its four corners places fall on the wrong modules and the read fails. Once the edge fit
has a lens (a known camera, or the frame's own estimate), the quad finder's near misses
whose modules the lens moves by more than :data:`BEND_MODULES` are decoded in straightened
pixels (the image resampled through the lens around them), where the marker is a plain
projective square again. What reads as one of the board's ids then goes through the same
edge fit and verification as every other marker.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.detect.decode import PatternTable, decode_quads
from artcal_ros.core.detect.edges import EdgeFit, same_edges
from artcal_ros.core.homography import apply_h, module_homographies

__all__ = ["BEND_MODULES", "bent", "read_through_lens"]

# modules moved by this share of a module against a homography: cells read off their middle
BEND_MODULES = 0.25
# pixels resampled around each quad, beyond its bounding box
_PAD_PX = 6
# spacing of the knots where the lens's map is evaluated exactly, straightened pixels
_STEP_PX = 4


def bent(quads: np.ndarray, lens: Any, bits: int) -> np.ndarray:
    """(R,) bool: inside the quads (R, 4, 2) the lens moves the modules (code cells next to
    the border and the middle) by more than BEND_MODULES from where a homography of the
    corners puts them."""
    if len(quads) == 0:
        return np.zeros(0, dtype=bool)
    n = bits + 2.0
    at = np.array([1.5, n / 2, n - 1.5])
    grid = np.broadcast_to(np.stack(np.meshgrid(at, at), axis=-1).reshape(1, -1, 2),
                           (len(quads), len(at) ** 2, 2))
    flat = apply_h(module_homographies(quads, bits), grid)
    straight = np.asarray(lens.undistort(quads.reshape(-1, 2)), dtype=np.float64)
    lensed = apply_h(module_homographies(straight.reshape(quads.shape), bits), grid)
    lensed = np.asarray(lens.distort(lensed.reshape(-1, 2))).reshape(flat.shape)
    moved = np.linalg.norm(lensed - flat, axis=2).max(axis=1)
    module = np.linalg.norm(quads - np.roll(quads, -1, axis=1), axis=2).mean(axis=1) / n
    return np.asarray(np.isfinite(moved) & (moved > BEND_MODULES * module))


def _decode_straightened(lin: np.ndarray, quads: np.ndarray, lens: Any,
                         patterns: PatternTable) -> tuple[np.ndarray, np.ndarray]:
    """Quads (D, 4, 2) in image pixels, board corner order, and ids (D,) of ``quads`` read
    in the lens's straightened pixels.

    Each quad is resampled side by side into one strip, scaled to the perimeter it has in
    the image (a straightened marker is a projective square at any scale; far out in a
    strong lens its straightened image is many times its size in the image).
    """
    straight: np.ndarray = np.asarray(lens.undistort(quads.reshape(-1, 2)), np.float64)
    straight = straight.reshape(-1, 4, 2)
    ok = np.isfinite(straight).all(axis=(1, 2))
    if hasattr(lens, "one_to_one"):
        ok &= lens.one_to_one(quads.reshape(-1, 2)).reshape(-1, 4).all(axis=1)
    quads, straight = quads[ok], straight[ok]
    if len(quads) == 0:
        return np.zeros((0, 4, 2)), np.zeros(0, dtype=np.int64)
    scale = _perimeter(quads) / np.maximum(_perimeter(straight), 1e-9)
    lo = straight.min(axis=1)
    local = (straight - lo[:, None]) * scale[:, None, None] + _PAD_PX
    size = np.ceil(local.max(axis=1)).astype(int) + _PAD_PX + 1
    left = np.concatenate([[0], np.cumsum(size[:, 0])])
    maps = np.full((int(size[:, 1].max()), int(left[-1]), 2), -1.0, np.float32)
    for r, (w, h) in enumerate(size):
        # the lens's map at knots _STEP_PX apart, bilinear between them (smooth there)
        ky, kx = np.mgrid[0:h + _STEP_PX:_STEP_PX, 0:w + _STEP_PX:_STEP_PX].astype(np.float64)
        at = (np.c_[kx.ravel(), ky.ravel()] - _PAD_PX) / scale[r] + lo[r]
        knots = np.asarray(lens.distort(at), np.float32).reshape(*kx.shape, 2)
        fy, fx = np.mgrid[0:h, 0:w].astype(np.float32) / _STEP_PX
        maps[:h, left[r]:left[r] + w] = cv2.remap(knots, fx, fy, cv2.INTER_LINEAR)
    patch = cv2.remap(np.asarray(lin, np.float32), maps[..., 0], maps[..., 1],
                      cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    shift = np.c_[left[:-1], np.zeros(len(quads))][:, None, :]
    dq, dids, which, _ = decode_quads(patch, local + shift, patterns)
    back = (dq - shift[which] - _PAD_PX) / scale[which, None, None] + lo[which, None]
    return np.asarray(lens.distort(back.reshape(-1, 2)), np.float64).reshape(-1, 4, 2), dids


def _perimeter(quads: np.ndarray) -> np.ndarray:
    """(R,) perimeter of quads (R, 4, 2)."""
    return np.asarray(np.linalg.norm(quads - np.roll(quads, -1, axis=1), axis=2).sum(axis=1))


def read_through_lens(lin: np.ndarray, lens: Any, near: np.ndarray, known: np.ndarray,
                      patterns: PatternTable, bits: int,
                      refine: Callable[[np.ndarray, np.ndarray], EdgeFit],
                      keep: Callable[[np.ndarray, np.ndarray], np.ndarray]
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ids (K,), corners (K, 4, 2) and corner sigmas (K, 4) of the markers read through the
    lens among the quad finder's near misses ``near`` (R, 4, 2), ids in ``known`` excluded.

    Args:
        refine: the edge fit of quads (Q, 4, 2) with ids (Q,), through the lens.
        keep: (Q,) bool, the fitted corners (Q, 4, 2) with ids (Q,) pass verification.
    """
    none = (np.zeros(0, dtype=np.int64), np.zeros((0, 4, 2)), np.zeros((0, 4)))
    near = near[bent(near, lens, bits)]
    if len(near) == 0:
        return none
    quads, ids = _decode_straightened(lin, near, lens, patterns)
    new = ~np.isin(ids, known)
    uniq, counts = np.unique(ids[new], return_counts=True)
    new &= np.isin(ids, uniq[counts == 1])
    quads, ids = quads[new], ids[new]
    if len(ids) == 0:
        return none
    fit = refine(quads, ids)
    h, w = lin.shape
    c = fit.corners_px
    ok = fit.ok & same_edges(c, quads) & np.isfinite(c).all(axis=(1, 2))
    ok &= ((c[..., 0] >= 0.5) & (c[..., 0] <= w - 1.5) & (c[..., 1] >= 0.5)
           & (c[..., 1] <= h - 1.5)).all(axis=1)
    ids, c, sigma = ids[ok], np.asarray(c[ok], dtype=np.float64), fit.corner_sigma_px[ok]
    good = keep(c, ids)
    return ids[good], c[good], sigma[good]
