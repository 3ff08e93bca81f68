"""Compile and cache the detector's kernels: ``python -m artcal_ros.synth.warm``.

The edge fit runs compiled (numba) kernels, compiled on first use and cached next to the
sources. The first detection on a new install would otherwise pay the compilation (tens of
seconds on a small machine); ``make`` runs this once when it sets up ``.venv``, so the node,
the CLI and the tests start from a warm cache. It renders a few frames of the default board
and detects them the ways the package does (cold, streamed, with a known camera, grey 8 and
16 bit, BGR, every polarity, over-exposed, and the node's marker tracker between them).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, detect
from artcal_ros.core.detect.sampling import bilinear
from artcal_ros.core.detect.step_model import pixel_esf
from artcal_ros.core.detect.tracking import MarkerTracker
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.photometry import Photometry
from artcal_ros.synth.poses import random_poses
from artcal_ros.synth.view import render_view


def warm() -> int:
    """Detect a handful of rendered frames; returns the markers found (a sanity figure)."""
    rng = np.random.default_rng(0)
    found = 0
    for polarity, preset, encoding in (("black", "webcam", "mono8"),
                                       ("mixed", "fisheye", "mono16"),
                                       ("white", "webcam", "bgr8")):
        board = Board(polarity=polarity)
        cam = Camera.preset(preset)
        stream = Detector(board)
        tracker = MarkerTracker(board)
        for rvec, tvec in random_poses(board, cam, 2, rng):
            view = render_view(board, cam, rvec, tvec, rng=rng, photometry=Photometry.clean(),
                               encoding=encoding)
            found += len(detect(view.image, board))
            dets = stream.detect(view.image)
            found += len(dets)
            found += len(detect(view.image, board, camera=cam))
            for _ in range(2):  # seeded, then followed into the same frame
                index, _markers = tracker.track(view.image)
                tracker.seed(index, dets)
    # an over-exposed frame: the clipped-frame paths (censored and held side fits)
    board = Board()
    cam = Camera.preset("webcam")
    for rvec, tvec in random_poses(board, cam, 1, rng):
        view = render_view(board, cam, rvec, tvec, rng=rng,
                           photometry=Photometry(exposure=4.0, defocus_px=0.7))
        found += len(detect(view.image, board))
    # A signature the frames above do not reach: grey images sampled as float64 besides
    # float32 (a clean clone's test run compiled it after this warm-up).
    for dtype in (np.float32, np.float64):
        bilinear(np.zeros((8, 8), dtype), np.array([1.5]), np.array([2.5]))
    # the pixel's edge-spread function called on its own (the renderer-free edge tests do)
    pixel_esf(0.1, 0.6, 1.0, 0.0)
    return found


def main() -> int:
    """Entry point; prints one line."""
    start = time.monotonic()
    n = warm()
    print(f"detector kernels compiled and cached in {time.monotonic() - start:.0f} s "
          f"({n} markers found in the warm-up frames)")
    return 0 if n > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
