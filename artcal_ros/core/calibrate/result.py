"""A calibration's result and how it is described: the one text summary (short and long) and
the JSON summary.

:func:`summary_text` is the one formatter of a :class:`CalibrationResult`; the node's
``~/calibrate`` answer and log (short) and ``artcal calibrate``'s output (long) both come from
it, through :func:`artcal_ros.core.calibrate.solve_run.solve_summary`, which adds the file
written.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from artcal_ros.core.calibrate.model import DIST_NAMES, INTRINSIC_NAMES, TIED_FOCAL
from artcal_ros.core.calibrate.verdict import verdict_of
from artcal_ros.core.camera import CameraModel, lens_spec


class DroppedView(NamedTuple):
    """A view left out of the solve: its position in the input list, its source, why."""

    view_index: int
    source: str
    reason: str


@dataclass(frozen=True)
class CalibrationResult:
    """A camera calibration and the figures that say how good it is.

    Attributes:
        camera_matrix: (3, 3) float64, pixels.
        dist_coeffs: (n,) float64, OpenCV order: plumb_bob (k1, k2, p1, p2, k3),
            rational_polynomial (k1, k2, p1, p2, k3, k4, k5, k6), equidistant (k1..k4).
        model: ``plumb_bob`` | ``rational_polynomial`` | ``equidistant``.
        image_size: (width, height), pixels.
        points: ``centers`` or ``corners``: the correspondences used.
        reprojection_rms_px: RMS of the point residual lengths, pixels.
        reprojection_std_px: standard deviation of the residuals per coordinate (the
            paper's figure: sqrt of the pooled x and y variance), pixels.
        reprojection_max_px: largest residual length, pixels.
        holdout_rms_px: k-fold cross-validation RMS over views, pixels (NaN if < 4 views).
        views_used: positions in the input list of the views in the final solve.
        views_dropped: the views left out, with the reason.
        points_dropped: number of outlier points removed from the views used.
        per_view_rms_px: (V,) RMS of each used view, aligned with ``views_used``.
        rvecs, tvecs: (V, 3) T_cam_board of each used view (Rodrigues, metres).
        std_devs: 1-sigma of each estimated parameter by name (fx, fy, cx, cy, k1, ...).
        projection_uncertainty_rms_px, projection_uncertainty_max_px: the 1-sigma image
            shift of the whole intrinsics' uncertainty over the image, pixels.
        coverage: share of an 8 x 6 grid of the image holding at least one point.
        warnings: what the data could not pin down and what to add.
        points_px: (P, 2) image points of the final solve; residuals_px: (P, 2) measured
            minus projected; point_view: (P,) their view's position in the input list.
        outliers_px: (Q, 2) image points dropped as outliers.
        solve_time_s: wall time of :func:`calibrate`, seconds.
        free: the parameters estimated (:func:`~.model.free_parameters`; ``f`` is fx = fy
            solved as one); the others were held (``calibrate.*`` parameters).
        weak_reason: why the view checks would have refused the set (solved anyway on
            request, ``accept_weak``); empty for a set they accept.
        covariance: (p, p) covariance of the free intrinsics, in the order of ``free``
            (:func:`~.quality.intrinsic_covariance`); empty when nothing was estimated.
    """

    camera_matrix: np.ndarray
    dist_coeffs: np.ndarray
    model: str
    image_size: tuple[int, int]
    points: str
    reprojection_rms_px: float
    reprojection_std_px: float
    reprojection_max_px: float
    holdout_rms_px: float
    views_used: tuple[int, ...]
    views_dropped: tuple[DroppedView, ...]
    points_dropped: int
    per_view_rms_px: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    std_devs: dict[str, float]
    projection_uncertainty_rms_px: float
    projection_uncertainty_max_px: float
    coverage: float
    warnings: tuple[str, ...]
    points_px: np.ndarray = field(repr=False)
    residuals_px: np.ndarray = field(repr=False)
    point_view: np.ndarray = field(repr=False)
    outliers_px: np.ndarray = field(repr=False)
    solve_time_s: float = 0.0
    free: tuple[str, ...] = ()
    weak_reason: str = ""
    covariance: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)), repr=False)

    @property
    def projection_uncertainty_px(self) -> float:
        """The projection uncertainty, RMS over the image, pixels (1-sigma)."""
        return self.projection_uncertainty_rms_px

    @property
    def camera(self) -> CameraModel:
        """The calibrated camera (K, full distortion vector of the model, image size)."""
        spec = lens_spec(self.model)
        dist = np.zeros(spec.n_dist)
        d = np.asarray(self.dist_coeffs, dtype=np.float64).ravel()[:spec.n_dist]
        dist[:len(d)] = d
        return CameraModel(self.model, self.camera_matrix, dist, self.image_size)

    def summary(self, *, long: bool = False) -> str:
        """The calibration in words: one line, or one screen with ``long``.

        The one formatter of a result (:func:`.summary.summary_text`): the node's
        ``~/calibrate`` answer and log and ``artcal calibrate``'s output both come from it.
        """
        return summary_text(self, long=long)

    def summary_line(self) -> str:
        """One line: model, intrinsics with 1-sigma, errors, views (``summary()``)."""
        return summary_text(self)

    def to_summary_dict(self) -> dict[str, Any]:
        """JSON-ready summary (the ``summary.json`` of ``artcal calibrate --report``)."""
        return summary_dict(self)


def _estimated(result: CalibrationResult, name: str) -> bool:
    """Whether ``name`` (fx, cx, k3, ...) was estimated rather than held."""
    if result.free:
        return name in result.free or (name in ("fx", "fy") and TIED_FOCAL in result.free)
    return name in result.std_devs


def _terms(result: CalibrationResult) -> list[str]:
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


def summary_text(result: CalibrationResult, *, long: bool = False) -> str:
    """The calibration in words: one line (model, intrinsics with 1-sigma, errors, views,
    warnings), or with ``long`` one screen (also the distortion, hold-out error, projection
    uncertainty, coverage and why views were left out), its first line the verdict
    (:func:`~artcal_ros.core.calibrate.verdict.verdict_of`). Held parameters say
    ``(fixed)``."""
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
    lines = [verdict_of(r).text(),
             f"camera: {r.model}, {r.image_size[0]}x{r.image_size[1]}, points: {r.points}",
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


def summary_dict(result: CalibrationResult) -> dict[str, Any]:
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
        "projection_uncertainty_px": {"rms": r.projection_uncertainty_rms_px,
                                      "max": r.projection_uncertainty_max_px},
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
        "verdict": verdict_of(r).as_dict(),
        "weak_reason": r.weak_reason,
    }
