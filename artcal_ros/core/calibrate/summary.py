"""How a calibration result is described: the one text summary (short and long) and the
JSON summary.

:func:`summary_text` is the one formatter of a
:class:`~artcal_ros.core.calibrate.pipeline.CalibrationResult`; the node's ``~/calibrate``
answer and log (short) and ``artcal calibrate``'s output (long) both come from it, through
:func:`artcal_ros.core.calibrate.session.session_summary`, which adds the file written.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from artcal_ros.core.calibrate.model import DIST_NAMES, INTRINSIC_NAMES, TIED_FOCAL


class DescribedResult(Protocol):
    """What the summaries read of a :class:`~artcal_ros.core.calibrate.pipeline.
    CalibrationResult` (see there for the meaning; named here so this module does not
    import the pipeline that imports it). Read-only, as the frozen result is."""

    @property
    def camera_matrix(self) -> np.ndarray: ...
    @property
    def dist_coeffs(self) -> np.ndarray: ...
    @property
    def model(self) -> str: ...
    @property
    def image_size(self) -> tuple[int, int]: ...
    @property
    def points(self) -> str: ...
    @property
    def reprojection_rms_px(self) -> float: ...
    @property
    def reprojection_std_px(self) -> float: ...
    @property
    def reprojection_max_px(self) -> float: ...
    @property
    def holdout_rms_px(self) -> float: ...
    @property
    def views_used(self) -> tuple[int, ...]: ...
    @property
    def views_dropped(self) -> Sequence[Any]: ...
    @property
    def points_dropped(self) -> int: ...
    @property
    def per_view_rms_px(self) -> np.ndarray: ...
    @property
    def std_devs(self) -> dict[str, float]: ...
    @property
    def projection_uncertainty_rms_px(self) -> float: ...
    @property
    def projection_uncertainty_max_px(self) -> float: ...
    @property
    def coverage(self) -> float: ...
    @property
    def warnings(self) -> tuple[str, ...]: ...
    @property
    def points_px(self) -> np.ndarray: ...
    @property
    def solve_time_s(self) -> float: ...
    @property
    def free(self) -> tuple[str, ...]: ...


def _estimated(result: DescribedResult, name: str) -> bool:
    """Whether ``name`` (fx, cx, k3, ...) was estimated rather than held."""
    if result.free:
        return name in result.free or (name in ("fx", "fy") and TIED_FOCAL in result.free)
    return name in result.std_devs


def _terms(result: DescribedResult) -> list[str]:
    """Each intrinsic and distortion term as ``name value±sigma`` or ``name value (fixed)``;
    a tied focal length is one term, ``fx = fy``."""
    K = result.camera_matrix
    values = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    values.update(zip(DIST_NAMES[result.model], result.dist_coeffs, strict=True))
    names = list(values)
    if TIED_FOCAL in result.free:
        names.remove("fy")
    out = []
    for n in names:
        shown = "fx = fy" if n == "fx" and TIED_FOCAL in result.free else n
        v = float(values[n])
        text = f"{v:.2f}" if n in INTRINSIC_NAMES else f"{v:.5g}"
        if _estimated(result, n):
            s = result.std_devs.get(n, float("nan"))
            out.append(f"{shown} {text}±{s:.2f}" if n in INTRINSIC_NAMES
                       else f"{shown} {text}±{s:.2g}")
        else:
            out.append(f"{shown} {text} (fixed)")
    return out


def summary_text(result: DescribedResult, *, long: bool = False) -> str:
    """The calibration in words: one line (model, intrinsics with 1-sigma, errors, views,
    warnings), or with ``long`` one screen (also the distortion, hold-out error, projection
    uncertainty, coverage and why views were left out). Held parameters say ``(fixed)``."""
    r = result
    terms = _terms(r)
    n_k = 3 if TIED_FOCAL in r.free else 4  # the intrinsics among the terms
    errors = (f"RMS {r.reprojection_rms_px:.3f} px, std {r.reprojection_std_px:.3f} px, max "
              f"{r.reprojection_max_px:.3f} px")
    views = (f"{len(r.views_used)} views used, {len(r.views_dropped)} left out, "
             f"{r.points_dropped} outlier points")
    if not long:
        line = (f"{r.model} {r.image_size[0]}x{r.image_size[1]} ({r.points}): "
                f"{' '.join(terms[:n_k])} px; reprojection {errors}; hold-out "
                f"{r.holdout_rms_px:.3f} px; {views}")
        if r.warnings:
            line += f"; warnings: {'; '.join(r.warnings)}"
        return line
    lines = [f"camera: {r.model}, {r.image_size[0]}x{r.image_size[1]}, points: {r.points}",
             "  " + "   ".join(terms[:n_k]) + " px",
             "  distortion " + "  ".join(terms[n_k:]),
             f"reprojection error: {errors}",
             f"hold-out (k-fold over views) RMS {r.holdout_rms_px:.3f} px; projection "
             f"uncertainty RMS {r.projection_uncertainty_rms_px:.3f} px, max "
             f"{r.projection_uncertainty_max_px:.3f} px",
             f"views: {len(r.views_used) + len(r.views_dropped)} given, {views}; "
             f"image coverage {100 * r.coverage:.0f}%"]
    reasons: dict[str, int] = {}
    for d in r.views_dropped:
        key = d.reason.split(":")[0]
        reasons[key] = reasons.get(key, 0) + 1
    for reason, count in sorted(reasons.items(), key=lambda kv: -kv[1])[:4]:
        lines.append(f"  {count} x {reason}")
    lines += [f"warning: {w}" for w in r.warnings]
    return "\n".join(lines)


def summary_dict(result: DescribedResult) -> dict[str, Any]:
    """JSON-ready summary (the ``summary.json`` of ``artcal calibrate --report``)."""
    r = result
    K = r.camera_matrix
    names = DIST_NAMES[r.model]
    return {
        "model": r.model,
        "points": r.points,
        "image_width": int(r.image_size[0]),
        "image_height": int(r.image_size[1]),
        "intrinsics": {"fx": float(K[0, 0]), "fy": float(K[1, 1]), "cx": float(K[0, 2]),
                       "cy": float(K[1, 2])},
        "distortion": {n: float(v) for n, v in zip(names, r.dist_coeffs, strict=True)},
        "std_devs": {k: float(v) for k, v in r.std_devs.items()},
        "camera_matrix": K.tolist(),
        "dist_coeffs": r.dist_coeffs.tolist(),
        "reprojection_rms_px": r.reprojection_rms_px,
        "reprojection_std_px": r.reprojection_std_px,
        "reprojection_max_px": r.reprojection_max_px,
        "holdout_rms_px": r.holdout_rms_px,
        "projection_uncertainty_rms_px": r.projection_uncertainty_rms_px,
        "projection_uncertainty_max_px": r.projection_uncertainty_max_px,
        "coverage": r.coverage,
        "points_used": len(r.points_px),
        "points_dropped": int(r.points_dropped),
        "views_used": [int(i) for i in r.views_used],
        "per_view_rms_px": [float(e) for e in r.per_view_rms_px],
        "views_dropped": [{"index": d.view_index, "source": d.source, "reason": d.reason}
                          for d in r.views_dropped],
        "warnings": list(r.warnings),
        "free_parameters": list(r.free),
        "solve_time_s": r.solve_time_s,
    }
