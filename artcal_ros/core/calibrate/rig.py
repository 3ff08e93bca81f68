"""Rig calibration: several cameras of fixed relative pose, solved together.

::

    rig = calibrate_rig({"left": [dets, ...], "right": [dets, ...]}, board,
                        image_sizes={"left": (w, h), "right": (w, h)})
    R, t = rig.extrinsics["left", "right"]   # x_right = R @ x_left + t, metres
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.rig_result import RigResult
from artcal_ros.core.detections import Detections


def calibrate_rig(detections: Mapping[str, Sequence[Detections | None]], board: Board, *,
                  image_sizes: Mapping[str, tuple[int, int]],
                  model: str | Mapping[str, str] = "plumb_bob", points: str = "corners",
                  fixed_intrinsics: Mapping[str, tuple[np.ndarray, np.ndarray]] | None = None,
                  k_coefficients: int = 0, fix_principal_point: bool = False,
                  fix_aspect_ratio: bool = False, zero_tangent_dist: bool = False,
                  max_frames: int = 60, weighted: bool = True,
                  progress: Callable[[str], None] | None = None) -> RigResult:
    """Calibrate a rig of cameras from synchronised detections (not yet implemented)."""
    raise NotImplementedError
