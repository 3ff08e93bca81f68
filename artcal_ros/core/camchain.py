"""Kalibr's ``camchain.yaml``: a rig's cameras and the transforms between neighbours.

The layout Kalibr writes (``kalibr_calibrate_cameras``) and reads (its ``CameraChainParameters``)::

    cam0:
      cam_overlaps: [1]
      camera_model: pinhole
      distortion_coeffs: [k1, k2, r1, r2]
      distortion_model: radtan
      intrinsics: [fu, fv, pu, pv]
      resolution: [width, height]
      rostopic: /left/image_raw
    cam1:
      T_cn_cnm1:                         # T_cam1_cam0: a point in cam0's frame -> cam1's
      - [r11, r12, r13, tx]
      - [r21, r22, r23, ty]
      - [r31, r32, r33, tz]
      - [0.0, 0.0, 0.0, 1.0]
      ...

Lens models: ``plumb_bob`` is Kalibr's ``pinhole`` + ``radtan`` (k1 k2 p1 p2: the same
coefficients in the same order) when k3 is zero; ``equidistant`` is ``pinhole`` +
``equidistant`` (k1..k4, OpenCV's fisheye). Kalibr has no model for a plumb_bob k3 or for
``rational_polynomial``: such a camera is written ``pinhole`` with ROS's model name and
all its coefficients (Kalibr refuses it; every other reader gets the whole lens), and
:func:`camchain_yaml` says so in its warnings.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from artcal_ros.core.camera import CameraModel
from artcal_ros.core.files import (
    write_text_atomic as write_text_atomic,  # rig files write through it
)


@dataclass(frozen=True)
class ChainCamera:
    """One camera of the chain.

    Attributes:
        name: the camera's name (for the warnings; Kalibr numbers them cam0, cam1, ...).
        camera: its calibration.
        rostopic: its image topic.
        T_cn_cnm1: (4, 4) T_this_previous (a point in the previous camera's frame -> this
            camera's, metres), None for the first camera.
        overlaps: indices of the cameras it shares board views with.
    """

    name: str
    camera: CameraModel
    rostopic: str
    T_cn_cnm1: np.ndarray | None
    overlaps: tuple[int, ...] = ()


def kalibr_model(camera: CameraModel) -> tuple[str, str, list[float], str]:
    """(camera_model, distortion_model, distortion_coeffs, warning or "") in Kalibr's names."""
    d = [float(v) for v in np.asarray(camera.dist, np.float64).ravel()]
    if camera.model == "equidistant":
        return "pinhole", "equidistant", (d + [0.0] * 4)[:4], ""
    if camera.model == "plumb_bob" and all(v == 0.0 for v in d[4:]):
        return "pinhole", "radtan", (d + [0.0] * 4)[:4], ""
    what = "k3" if camera.model == "plumb_bob" else "rational_polynomial"
    return ("pinhole", camera.model, d,
            f"its lens ({what}) has no Kalibr model; written as distortion_model "
            f"{camera.model} with all {len(d)} coefficients, which Kalibr does not read")


def _numbers(values: Sequence[float]) -> str:
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def camchain_yaml(cameras: Sequence[ChainCamera]) -> tuple[str, list[str]]:
    """(the camchain.yaml text of ``cameras`` in order, warnings naming each camera Kalibr
    cannot read)."""
    lines: list[str] = []
    warnings: list[str] = []
    for i, cam in enumerate(cameras):
        model, dist_model, coeffs, warning = kalibr_model(cam.camera)
        if warning:
            warnings.append(f"camchain.yaml cam{i} ({cam.name}): {warning}")
        K = cam.camera.K
        lines.append(f"cam{i}:")
        if cam.T_cn_cnm1 is not None:
            T = np.asarray(cam.T_cn_cnm1, np.float64).reshape(4, 4)
            lines.append("  T_cn_cnm1:")
            lines.extend(f"  - {_numbers(row.tolist())}" for row in T)
        lines.append(f"  cam_overlaps: [{', '.join(str(j) for j in cam.overlaps)}]")
        lines.append(f"  camera_model: {model}")
        lines.append(f"  distortion_coeffs: {_numbers(coeffs)}")
        lines.append(f"  distortion_model: {dist_model}")
        lines.append(f"  intrinsics: {_numbers([K[0, 0], K[1, 1], K[0, 2], K[1, 2]])}")
        lines.append(f"  resolution: [{cam.camera.size[0]}, {cam.camera.size[1]}]")
        lines.append(f"  rostopic: {cam.rostopic}")
    return "\n".join(lines) + "\n", warnings


def chain_cameras(names: Sequence[str], cameras: Mapping[str, CameraModel],
                  transforms: Mapping[tuple[str, str], np.ndarray],
                  topics: Mapping[str, str],
                  shared_frames: Mapping[tuple[str, str], int]) -> list[ChainCamera]:
    """The chain of a rig in ``names`` order.

    Args:
        names: the cameras, the first the chain's start.
        cameras: name -> calibration.
        transforms: (a, b) -> (4, 4) T_b_a for each consecutive pair (a before b).
        topics: name -> image topic.
        shared_frames: (a, b) -> frames both see the board in (either order).
    """
    out = []
    for i, n in enumerate(names):
        overlaps = tuple(j for j, m in enumerate(names) if m != n and
                         max(shared_frames.get((n, m), 0), shared_frames.get((m, n), 0)) > 0)
        out.append(ChainCamera(n, cameras[n], topics[n],
                               None if i == 0 else transforms[names[i - 1], n], overlaps))
    return out
