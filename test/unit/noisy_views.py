"""Views of the default board with exact marker corners plus Gaussian noise, for solve tests."""

from __future__ import annotations

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.synth import Camera, random_poses
from artcal_ros.synth.poses import marker_truth

BOARD = Board()


def noisy_views(cam: Camera, n: int, seed: int, noise_px: float = 0.03) -> list[Detections]:
    """Exact marker corners of ``n`` random views plus Gaussian noise (centres: their mean)."""
    rng = np.random.default_rng(seed)
    out = []
    for k, (rvec, tvec) in enumerate(random_poses(BOARD, cam, n, rng)):
        corners, _, inside, _ = marker_truth(BOARD, cam, rvec, tvec)
        noisy = corners[inside] + rng.normal(0.0, noise_px, corners[inside].shape)
        out.append(Detections(BOARD.ids[inside], noisy, noisy.mean(axis=1), cam.size,
                              source=f"view{k}"))
    return out
