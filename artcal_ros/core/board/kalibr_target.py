"""Kalibr target YAML files (``target_type: aprilgrid | checkerboard | circlegrid``) as ``board.*``
parameters.

Kalibr describes its calibration targets in a small YAML file (``kalibr_calibrate_cameras
--target april_6x6.yaml``). The translation (also in docs/conventions.md):

- ``aprilgrid``: tagCols -> board.cols, tagRows -> board.rows, tagSize -> board.marker_length
  (metres), tagSize x tagSpacing -> board.marker_separation (tagSpacing is a ratio).
- ``checkerboard``: targetCols -> board.cols, targetRows -> board.rows (inner corners, as
  camera_calibration's ``--size``), rowSpacingMeters = colSpacingMeters -> board.square_length
  (this package's chessboard has square squares; different spacings are refused).

- ``circlegrid``: targetCols -> board.cols, targetRows -> board.rows (Kalibr passes them to
  OpenCV's ``findCirclesGrid`` as its patternSize, so the point order and ids are OpenCV's),
  spacingMeters -> board.square_length, asymmetricGrid (default false) -> board.type
  ``acircles`` when true, else ``circles``. Kalibr's asymmetric layout is OpenCV's; its
  symmetric grid has x and y swapped (point ``r * cols + c`` at ``(r s, c s)``), a mirrored
  board frame that leaves the intrinsics as they are (docs/conventions.md).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import yaml

from artcal_ros.core.errors import ParameterError

_FIELDS: dict[str, tuple[str, ...]] = {
    "aprilgrid": ("tagCols", "tagRows", "tagSize", "tagSpacing"),
    "checkerboard": ("targetCols", "targetRows", "rowSpacingMeters", "colSpacingMeters"),
    "circlegrid": ("targetCols", "targetRows", "spacingMeters"),
}
_COUNTS = ("tagCols", "tagRows", "targetCols", "targetRows")


def _read(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text()
    except OSError as e:
        raise ParameterError(f"--target {path}: cannot read it: {e.strerror or e}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        where = getattr(e, "problem_mark", None)
        at = f" (line {where.line + 1})" if where is not None else ""
        raise ParameterError(f"--target {path}: not valid YAML{at}; expected a Kalibr target "
                             "file with target_type and its fields") from None
    if not isinstance(data, dict):
        raise ParameterError(f"--target {path}: expected a mapping with target_type "
                             "(aprilgrid, checkerboard or circlegrid) and its fields")
    return data


def _field(path: Path, data: dict[str, Any], name: str) -> float:
    if name not in data:
        raise ParameterError(f"--target {path}: {data['target_type']} needs {name}; "
                             f"give {', '.join(_FIELDS[data['target_type']])}")
    value = data[name]
    integral = name in _COUNTS
    ok_type = isinstance(value, int) if integral else isinstance(value, int | float)
    if isinstance(value, bool) or not ok_type or not math.isfinite(float(value)):
        kind = "an integer" if integral else "a number"
        raise ParameterError(f"--target {path}: {name}: {value!r} is not {kind}")
    if not value > 0:
        raise ParameterError(f"--target {path}: {name}: {value!r} must be > 0")
    return float(value)


def target_params(path: str | Path) -> dict[str, Any]:
    """The ``board.*`` parameters of a Kalibr target YAML file.

    Args:
        path: the file (Kalibr's format: ``target_type`` and that type's fields; sizes in
            metres).

    Returns:
        a flat dict of ``board.*`` overrides (see the module docstring for the mapping).

    Raises:
        ParameterError: the file cannot be read, is not a Kalibr target, or a field is
            missing or out of range; the message names the file and the field.
    """
    p = Path(path)
    data = _read(p)
    kind = data.get("target_type")
    if kind not in _FIELDS:
        raise ParameterError(f"--target {p}: target_type {kind!r} is not a Kalibr target "
                             "type this reads; use aprilgrid, checkerboard or circlegrid")
    f = {name: _field(p, data, name) for name in _FIELDS[str(kind)]}
    if kind == "aprilgrid":
        return {"board.type": "aprilgrid", "board.dictionary": "tag36h11",
                "board.cols": int(f["tagCols"]), "board.rows": int(f["tagRows"]),
                "board.marker_length": f["tagSize"],
                # rounded to the nanometre: 0.088 x 0.3 reads 0.0264, not 0.026399999999999996
                "board.marker_separation": round(f["tagSize"] * f["tagSpacing"], 9),
                "board.polarity": "black", "board.first_id": 0}
    if kind == "circlegrid":
        return _circlegrid(p, data, f)
    if int(f["targetCols"]) < 2 or int(f["targetRows"]) < 2:
        raise ParameterError(f"--target {p}: a checkerboard needs at least 2 x 2 inner "
                             "corners (targetCols, targetRows)")
    row, col = f["rowSpacingMeters"], f["colSpacingMeters"]
    if not math.isclose(row, col, rel_tol=1e-9):
        raise ParameterError(f"--target {p}: rowSpacingMeters {row} and colSpacingMeters "
                             f"{col} differ; a chessboard here has square squares")
    return {"board.type": "chessboard", "board.cols": int(f["targetCols"]),
            "board.rows": int(f["targetRows"]), "board.square_length": row}


def _circlegrid(path: Path, data: dict[str, Any], f: dict[str, float]) -> dict[str, Any]:
    """The ``board.*`` parameters of a Kalibr circlegrid (see the module docstring)."""
    asymmetric = data.get("asymmetricGrid", False)
    if isinstance(asymmetric, int) and not isinstance(asymmetric, bool) and asymmetric in (0, 1):
        asymmetric = bool(asymmetric)
    if not isinstance(asymmetric, bool):
        raise ParameterError(f"--target {path}: asymmetricGrid: {asymmetric!r} is not true or "
                             "false")
    if int(f["targetCols"]) < 2 or int(f["targetRows"]) < 2:
        raise ParameterError(f"--target {path}: a circle grid needs at least 2 x 2 circles "
                             "(targetCols, targetRows)")
    return {"board.type": "acircles" if asymmetric else "circles",
            "board.cols": int(f["targetCols"]), "board.rows": int(f["targetRows"]),
            "board.square_length": f["spacingMeters"]}
