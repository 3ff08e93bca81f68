"""A rig's solve options and output files, shared by ``artcal calibrate --camera`` and the
calibrator node with ``cameras``.

- :func:`rig_solve_kwargs`: the keyword arguments of
  :func:`~artcal_ros.core.calibrate.rig.calibrate_rig` from the flat parameters;
- :func:`write_rig_files`: ``DIR/<camera>.yaml`` per camera (camera_calibration_parsers
  YAML, a pair with its stereo rectification R and P) and ``DIR/camchain.yaml`` (Kalibr's);
- :func:`frame_transforms`: the extrinsics as tf transforms between the cameras' frames.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.core.calibrate.rig_result import RigResult
from artcal_ros.core.camera_info import CameraInfoData


def rig_solve_kwargs(params: Mapping[str, Any], names: Sequence[str],
                     fixed: Mapping[str, CameraInfoData] | None = None) -> dict[str, Any]:
    """``calibrate_rig``'s options from the parameters (``camera_model``, ``points``, the
    ``calibrate.*`` options); the cameras in ``fixed`` keep their intrinsics and model.

    Args:
        params: validated parameters (:func:`artcal_ros.core.params.load_params`).
        names: the rig's cameras.
        fixed: camera -> its calibration whose intrinsics are kept
            (``calibrate.fix_intrinsics``), or None.
    """
    fixed = fixed or {}
    model = str(params["camera_model"])
    return {"model": {n: (fixed[n].distortion_model if n in fixed else model) for n in names},
            "points": str(params["points"]),
            "fixed_intrinsics": {n: (i.camera_matrix, i.dist_coeffs)
                                 for n, i in fixed.items()} or None,
            "k_coefficients": int(params["calibrate.k_coefficients"]),
            "fix_principal_point": bool(params["calibrate.fix_principal_point"]),
            "fix_aspect_ratio": bool(params["calibrate.fix_aspect_ratio"]),
            "zero_tangent_dist": bool(params["calibrate.zero_tangent_dist"])}


def write_rig_files(directory: str | Path, rig: RigResult, topics: Mapping[str, str]
                    ) -> tuple[list[Path], list[str]]:
    """``directory/<name>.yaml`` per camera and ``directory/camchain.yaml``, each atomically.

    Args:
        directory: where to write (made if missing).
        rig: the solved rig.
        topics: camera -> its image topic (camchain's ``rostopic``).

    Returns:
        (the files written, the camchain's warnings).

    Raises:
        ArtcalError: a file cannot be written.
    """
    from artcal_ros.core.camchain import camchain_yaml, chain_cameras, write_text_atomic
    from artcal_ros.core.camera_info import write_camera_info_yaml

    out = Path(directory).expanduser()
    chain = chain_cameras(rig.names, {n: rig.cameras[n].camera for n in rig.names},
                          {p: rig.transform(*p) for p in rig.consecutive_pairs}, topics,
                          rig.shared_frames)
    text, warnings = camchain_yaml(chain)
    written = []
    for n in rig.names:
        written.append(out / f"{n}.yaml")
        write_camera_info_yaml(written[-1], rig.camera_info(n))
    written.append(out / "camchain.yaml")
    write_text_atomic(written[-1], text)
    return written, warnings


def frame_transforms(rig: RigResult, frame_ids: Mapping[str, str]
                     ) -> list[tuple[str, str, np.ndarray, tuple[float, float, float, float]]]:
    """Each camera's frame in the reference camera's, as tf states a transform.

    Args:
        rig: the solved rig.
        frame_ids: camera -> its frame id (the images' header frame_id).

    Returns:
        one ``(parent frame, child frame, translation (3,) metres, rotation (x, y, z, w))``
        per camera after the reference: T_reference_camera, mapping a point in the child's
        frame into the parent's (the inverse of ``rig.extrinsics[reference, camera]``); none
        when two cameras share a frame id.
    """
    ref = rig.reference
    if len({frame_ids[n] for n in rig.names}) < len(rig.names):
        return []
    out = []
    for n in rig.names[1:]:
        T = rig.transform(n, ref)   # T_ref_n
        out.append((frame_ids[ref], frame_ids[n], T[:3, 3].copy(), quaternion_xyzw(T[:3, :3])))
    return out


def quaternion_xyzw(R: np.ndarray) -> tuple[float, float, float, float]:
    """The unit quaternion (x, y, z, w), w >= 0, of a rotation matrix ``R`` (3, 3)."""
    m = np.asarray(R, dtype=np.float64)
    # the largest of the four squared components is computed first: no cancellation
    trace = float(np.trace(m))
    diag = np.diag(m)
    k = int(np.argmax([*diag, trace]))
    if k == 3:
        w = 0.5 * np.sqrt(1.0 + trace)
        q = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1], 0.0]) / (4 * w)
        q[3] = w
    else:
        i, j, l_ = k, (k + 1) % 3, (k + 2) % 3
        q = np.zeros(4)
        q[i] = 0.5 * np.sqrt(max(1.0 + m[i, i] - m[j, j] - m[l_, l_], 0.0))
        q[j] = (m[j, i] + m[i, j]) / (4 * q[i])
        q[l_] = (m[l_, i] + m[i, l_]) / (4 * q[i])
        q[3] = (m[l_, j] - m[j, l_]) / (4 * q[i])
    q /= np.linalg.norm(q)
    if q[3] < 0:
        q = -q
    return float(q[0]), float(q[1]), float(q[2]), float(q[3])
