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
# straightened pixels resampled around the quads, beyond their bounding box
_PAD_PX = 4


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
    in the lens's straightened pixels."""
    straight = np.asarray(lens.undistort(quads.reshape(-1, 2)), dtype=np.float64)
    if hasattr(lens, "one_to_one"):
        inside = lens.one_to_one(quads.reshape(-1, 2)).reshape(-1, 4).all(axis=1)
        straight = straight.reshape(-1, 4, 2)[inside].reshape(-1, 2)
    if len(straight) == 0 or not np.isfinite(straight).all():
        return np.zeros((0, 4, 2)), np.zeros(0, dtype=np.int64)
    x0, y0 = np.floor(straight.min(axis=0)).astype(int) - _PAD_PX
    x1, y1 = np.ceil(straight.max(axis=0)).astype(int) + _PAD_PX
    yy, xx = np.mgrid[y0:y1 + 1, x0:x1 + 1].astype(np.float64)
    src = np.asarray(lens.distort(np.c_[xx.ravel(), yy.ravel()]), dtype=np.float32)
    src = src.reshape(*xx.shape, 2)
    patch = cv2.remap(np.asarray(lin, np.float32), src[..., 0], src[..., 1], cv2.INTER_LINEAR,
                      borderMode=cv2.BORDER_REPLICATE)
    local = straight.reshape(-1, 4, 2) - np.array([x0, y0], dtype=np.float64)
    dq, dids, _, _ = decode_quads(patch, local, patterns)
    back = lens.distort((dq + np.array([x0, y0], dtype=np.float64)).reshape(-1, 2))
    return np.asarray(back, dtype=np.float64).reshape(-1, 4, 2), dids


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
