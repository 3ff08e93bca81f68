"""The verdict on a calibration: good, usable or poor, with the reason in words.

Derived only from figures the result already has (docs/conventions.md, "Verdict", states
the thresholds): the reprojection RMS, the 1-sigma of fx, fy, cx, cy relative to their
values, the projection uncertainty over the image (RMS, over the image diagonal), and the share
of the views given
that the solve could use. Each figure is rated on its own; the verdict is the worst rating,
and its reason names the figures that set it. A set solved although the view checks refuse
it (``accept_weak``) is poor whatever its figures, and says so with its uncertainty.

::

    v = verdict_of(result)
    v.level      # "good" | "usable" | "poor"
    v.text()     # "verdict: good: reprojection RMS 0.165 px, ..."
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

__all__ = ["LEVELS", "Figures", "Verdict", "verdict_of"]


class _Dropped(Protocol):
    @property
    def reason(self) -> str: ...


class Figures(Protocol):
    """What a verdict reads (a :class:`~artcal_ros.core.calibrate.result.CalibrationResult`
    has it all; the result module uses this one, so this one cannot import it)."""

    @property
    def camera_matrix(self) -> np.ndarray: ...
    @property
    def std_devs(self) -> Mapping[str, float]: ...
    @property
    def reprojection_rms_px(self) -> float: ...
    @property
    def projection_uncertainty_rms_px(self) -> float: ...
    @property
    def views_used(self) -> Sequence[int]: ...
    @property
    def views_dropped(self) -> Sequence[_Dropped]: ...
    @property
    def weak_reason(self) -> str: ...
    @property
    def image_size(self) -> tuple[int, int]: ...

LEVELS = ("good", "usable", "poor")
# (good at or below, usable at or below); above: poor
RMS_PX = (0.5, 1.0)
RELATIVE_STD = (0.01, 0.05)  # 1-sigma of fx, fy, cx, cy over the value
# projection uncertainty, RMS over the image, over the image diagonal: on the scale of the
# relative 1-sigma above (fx known to 0.1 % moves a 640 x 480 image's edge by ~0.3 px)
UNCERTAINTY_OF_DIAGONAL = (0.001, 0.005)
USED_SHARE = 0.5  # fewer of the views given used than this: usable at best
NOT_SELECTED = "not selected"  # views left out only as similar to kept ones are not refused


@dataclass(frozen=True)
class Verdict:
    """A calibration's verdict.

    Attributes:
        level: ``good``, ``usable`` or ``poor``.
        reason: the figures in words, those that set the level first.
    """

    level: str
    reason: str

    def text(self) -> str:
        """One line: ``verdict: <level>: <reason>``."""
        return f"verdict: {self.level}: {self.reason}"

    def as_dict(self) -> dict[str, str]:
        """JSON-ready ``{"level", "reason"}``."""
        return {"level": self.level, "reason": self.reason}


def _rate(value: float, bounds: tuple[float, float]) -> int:
    """0 good, 1 usable, 2 poor (NaN or inf: poor)."""
    if not np.isfinite(value):
        return 2
    return 0 if value <= bounds[0] else 1 if value <= bounds[1] else 2


def _relative_std(result: Figures) -> tuple[float, str]:
    """The largest 1-sigma over value among the estimated fx, fy, cx, cy, and its name."""
    K = result.camera_matrix
    values = {"fx": K[0, 0], "fy": K[1, 1], "cx": K[0, 2], "cy": K[1, 2]}
    rel: dict[str, float] = {}
    for n, v in values.items():
        s = result.std_devs.get(n)
        if s is not None:  # held ones have none
            q = abs(float(s) / float(v)) if float(v) != 0.0 else float("inf")
            rel[n] = q if np.isfinite(q) else float("inf")
    if not rel:
        return 0.0, ""
    name = max(rel, key=lambda n: rel[n])
    return rel[name], name


def verdict_of(result: Figures) -> Verdict:
    """The verdict on ``result`` (see the module docstring)."""
    r = result
    rel, rel_name = _relative_std(r)
    unc = float(r.projection_uncertainty_rms_px)
    diagonal = float(np.hypot(*r.image_size))
    refused = sum(1 for d in r.views_dropped if not d.reason.startswith(NOT_SELECTED))
    used = len(r.views_used)
    given = used + refused
    rated: list[tuple[int, str]] = [
        (_rate(r.reprojection_rms_px, RMS_PX),
         f"reprojection RMS {r.reprojection_rms_px:.3f} px"),
        (_rate(unc / diagonal, UNCERTAINTY_OF_DIAGONAL),
         f"projection uncertainty {unc:.3f} px RMS over the image "
         f"({100 * unc / diagonal:.2g} % of its diagonal)"),
    ]
    if rel_name:
        rated.append((_rate(rel, RELATIVE_STD),
                      f"focal length and principal point known to {100 * rel:.2g} % "
                      f"(1-sigma, worst: {rel_name})"))
    share = used / given if given else 0.0
    rated.append((0 if share >= USED_SHARE else 1,
                  f"{used} of {given} views used" + (
                      "" if share >= USED_SHARE else
                      " (the board was not found or not usable in the others)")))
    worst = max(k for k, _ in rated)
    if r.weak_reason:
        why = r.weak_reason.split(";")[0]
        uncertain = "; ".join(text for _, text in rated[1:3])
        return Verdict("poor", f"solved only because --accept-weak was given although "
                               f"{why}; uncertainty: {uncertain}")
    order = sorted(rated, key=lambda kt: -kt[0])
    limiting = [text for k, text in order if k == worst and worst > 0]
    rest = [text for k, text in order if not (k == worst and worst > 0)]
    if limiting:
        reason = "limited by " + "; ".join(limiting)
        if rest:
            reason += "; otherwise " + ", ".join(rest)
    else:
        reason = ", ".join(rest)
    return Verdict(LEVELS[worst], reason)
