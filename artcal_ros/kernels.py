"""The package's compiled (numba) kernels: compile them ahead of use, and tell which compiled.

``python -m artcal_ros.kernels`` compiles and caches every kernel the detector runs. numba
compiles a kernel on its first call and caches the machine code in the ``__pycache__`` next to
its source, stamped with a hash of the source's content, so the cache stays valid wherever the
files are copied or installed. ``setup.py`` runs this module against the built tree (or, for
an editable install, the source tree) whenever the package is built or installed: by
``colcon build`` (also ``--symlink-install``), ``pip install`` of the source or of a wheel
built here, and ``make``. The first detection of a fresh install then loads machine code
instead of compiling it (tens of seconds on a small machine).

The cache holds code for the CPU (name and features) it was made on and for one numba
version: elsewhere it is a miss and the kernels compile on first use, as they would without
it. Where the package directory is not writable, numba keeps its cache in a per-user
directory instead, and the kernels compile once per user.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from numba.core.dispatcher import Dispatcher

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, detect
from artcal_ros.core.detect.sampling import bilinear, bilinear_at
from artcal_ros.core.detect.step_model import pixel_esf
from artcal_ros.core.homography import apply_one
from artcal_ros.core.live.tracking import MarkerTracker
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.photometry import Photometry
from artcal_ros.synth.poses import random_poses
from artcal_ros.synth.view import render_view

PACKAGE = "artcal_ros"


def warm() -> int:
    """Detect a handful of rendered frames the ways the package does, so that every kernel
    signature the node, the CLI and the tests call is compiled and cached; returns the markers
    found (a sanity figure).

    The frames: the default board in every polarity, grey 8 and 16 bit and BGR, detected cold,
    streamed and with a known camera, the node's marker tracker between them, and an
    over-exposed frame.
    """
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
    # the one-point sampler and homography map the kernels share, called from Python
    bilinear_at(np.zeros((8, 8)), 1.5, 2.5)
    apply_one(np.eye(3), 1.5, 2.5)
    # the pixel's edge-spread function called on its own (the renderer-free edge tests do)
    pixel_esf(0.1, 0.6, 1.0, 0.0)
    return found


def dispatchers() -> dict[str, Dispatcher]:
    """The package's numba kernels in the modules imported so far, by ``module.function``."""
    found: dict[str, Dispatcher] = {}
    for name, module in list(sys.modules.items()):
        if module is None or not (name == PACKAGE or name.startswith(f"{PACKAGE}.")):
            continue
        for value in vars(module).values():
            if isinstance(value, Dispatcher):
                func = value.py_func
                found[f"{func.__module__}.{func.__qualname__}"] = value
    return found


def compiled_here() -> dict[str, list[str]]:
    """The kernels this process compiled instead of loading them from the cache: the
    signatures of each (empty when every call so far was served by the cache)."""
    return {name: [str(sig) for sig in kernel.stats.cache_misses]
            for name, kernel in dispatchers().items() if kernel.stats.cache_misses}


def main() -> int:
    """Entry point: compile and cache the kernels; prints what it did and where the cache is."""
    start = time.monotonic()
    n = warm()
    kernels = dispatchers()
    compiled = sum(len(k.stats.cache_misses) for k in kernels.values())
    loaded = sum(len(k.stats.cache_hits) for k in kernels.values())
    print(f"{PACKAGE} kernels ready in {time.monotonic() - start:.0f} s: {compiled} compiled, "
          f"{loaded} loaded from the cache ({n} markers found in the warm-up frames)")
    package_dir = Path(__file__).parent
    elsewhere = sorted({path for path in (k.stats.cache_path for k in kernels.values())
                        if path is not None and not Path(path).is_relative_to(package_dir)})
    if elsewhere:
        print(f"the cache is not in the package (not writable, or NUMBA_CACHE_DIR set): "
              f"{', '.join(elsewhere)}")
    return 0 if n > 0 else 1


if __name__ == "__main__":
    sys.exit(main())
