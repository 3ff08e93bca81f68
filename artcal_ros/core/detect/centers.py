"""Marker centers: the intersection of the refined quad's diagonals.

Under a pinhole projection the image of a square's center is exactly the
intersection of its image diagonals, so the center needs no edge of its own.
"""

from __future__ import annotations

import numpy as np

from artcal_ros.core.detect.lens import DivisionLens, Lens


def diagonal_centers(corners: np.ndarray, corner_sigma: np.ndarray,
                     lens: Lens | None) -> tuple[np.ndarray, np.ndarray]:
    """Marker centers as the intersection of the quad diagonals, and their 1-sigma errors.

    With a lens model the corners are undistorted first and the intersection is
    distorted back, so the result is the true image of the center; without one,
    the error is of second order in the distortion's variation across the marker
    (a few thousandths of a pixel for markers below ~100 px in ordinary lenses).

    Args:
        corners: (M, 4, 2) pixels, TL, TR, BR, BL.
        corner_sigma: (M, 4) 1-sigma corner errors, pixels.
        lens: optional lens model.

    Returns:
        centers (M, 2) pixels and sigmas (M,) pixels (the sigma of the mean of
        four independent corners, exact for a parallelogram).
    """
    M = len(corners)
    if M == 0:
        return np.zeros((0, 2)), np.zeros(0)
    q = corners if lens is None else lens.undistort(corners.reshape(-1, 2)).reshape(M, 4, 2)
    if isinstance(lens, DivisionLens):
        # a marker beyond the estimated model's fold: its plain diagonals (better than the
        # model's round trip through a fold)
        out = np.asarray(~lens.one_to_one(corners).reshape(M, 4).all(axis=1), dtype=bool)
        q[out] = corners[out]
    h = np.concatenate([q, np.ones((M, 4, 1))], axis=2)
    d1 = np.cross(h[:, 0], h[:, 2])
    d2 = np.cross(h[:, 1], h[:, 3])
    c = np.cross(d1, d2)
    with np.errstate(all="ignore"):
        centers = c[:, :2] / c[:, 2:3]
    # parallel diagonals (a degenerate quad): its corners' mean is the best guess
    bad = ~np.isfinite(centers).all(axis=1)
    centers[bad] = q[bad].mean(axis=1)
    if lens is not None:
        mapped = lens.distort(centers)
        centers = mapped if not isinstance(lens, DivisionLens) else np.where(
            out[:, None], centers, mapped)
    sigma = 0.5 * np.sqrt(np.mean(np.asarray(corner_sigma, dtype=np.float64) ** 2, axis=1))
    return centers, sigma
