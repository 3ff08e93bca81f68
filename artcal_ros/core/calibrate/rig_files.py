"""A rig's solve options and output files, shared by ``artcal calibrate --camera`` and the
calibrator node with ``cameras``.

- :func:`rig_solve_kwargs`: the keyword arguments of
  :func:`~artcal_ros.core.calibrate.rig.calibrate_rig` from the flat parameters;
- :func:`write_rig_files`: ``DIR/<camera>.yaml`` per camera (camera_calibration_parsers
  YAML, a pair with its stereo rectification R and P) and ``DIR/camchain.yaml`` (Kalibr's).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

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
