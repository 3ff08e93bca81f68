"""The words of a calibration report: the first page's verdict and advice for a user who knows
no calibration theory, the intrinsics table, the tone-curve and board checks, the views left
out.

Everything here is plain text built from the result and ``summary.json``'s ``tone_curve`` and
``board_check``; :mod:`artcal_ros.core.calibrate.report_pages` lays it out.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from artcal_ros.core.calibrate.model import DIST_NAMES, INTRINSIC_NAMES, TIED_FOCAL
from artcal_ros.core.calibrate.result import CalibrationResult, DroppedView
from artcal_ros.core.calibrate.verdict import (
    NOT_SELECTED,
    RELATIVE_STD,
    RMS_PX,
    UNCERTAINTY_OF_DIAGONAL,
    USED_SHARE,
    verdict_of,
)

__all__ = ["PlainVerdict", "checks_text", "dropped_kinds", "intrinsics_rows", "plain_verdict",
           "refused_verdict"]

# headline of each verdict level, in a user's words
_HEADLINES = {
    "good": "GOOD: this calibration can be used.",
    "usable": "USABLE: it works, but could be better.",
    "poor": "POOR: do not rely on it yet.",
}
# below this share of the 8 x 6 image grid holding points, the image edges are guessed
_COVERAGE_ADVICE = 0.75


@dataclass(frozen=True)
class PlainVerdict:
    """The first page of a report in words.

    Attributes:
        level: ``good``, ``usable``, ``poor`` or ``refused`` (no calibration).
        headline: one short sentence.
        meaning: what the figures mean, in plain words (a few sentences).
        actions: what to do next, one instruction each (empty: nothing needed).
        figures: the key figures, ``(name, value in words)``.
        notes: the solver's warnings and the checks' findings, verbatim.
    """

    level: str
    headline: str
    meaning: str
    actions: tuple[str, ...]
    figures: tuple[tuple[str, str], ...]
    notes: tuple[str, ...]

    def text(self) -> str:
        """The whole page as plain text (what a log or a terminal shows)."""
        lines = [self.headline, "", self.meaning]
        if self.actions:
            lines += ["", "What to do:"] + [f"- {a}" for a in self.actions]
        lines += ["", *(f"{k}: {v}" for k, v in self.figures)]
        if self.notes:
            lines += ["", "Notes:"] + [f"- {n}" for n in self.notes]
        return "\n".join(lines)


def _relative_std(result: CalibrationResult) -> float:
    K = result.camera_matrix
    rel = [abs(result.std_devs[n] / v) for n, v in
           (("fx", K[0, 0]), ("fy", K[1, 1]), ("cx", K[0, 2]), ("cy", K[1, 2]))
           if n in result.std_devs and v != 0]
    return max(rel) if rel else 0.0


def _actions(result: CalibrationResult, board_check: Mapping[str, Any] | None,
             feature: str) -> list[str]:
    """What to do, from the figures that are not good (the verdict's thresholds)."""
    r = result
    out: list[str] = []
    if r.weak_reason:
        out.append("Take more pictures: the set was solved only because --accept-weak was "
                   f"given, although {r.weak_reason.split(';')[0]}.")
    if not np.isfinite(r.reprojection_rms_px) or r.reprojection_rms_px > RMS_PX[0]:
        lens = {"plumb_bob": "; for a wide-angle lens try camera_model rational_polynomial "
                             "or equidistant",
                "rational_polynomial": "; for a fisheye lens try camera_model equidistant",
                "equidistant": "; for a lens that is not a fisheye try camera_model "
                               "rational_polynomial"}.get(r.model, "")
        out.append("The board's points do not fit the camera well. Check the board settings "
                   "(type, size, marker length) against the printed board, that the board is "
                   f"flat and the pictures are sharp (hold still, more light){lens}.")
    diagonal = float(np.hypot(*r.image_size))
    unc = r.projection_uncertainty_rms_px
    if not np.isfinite(unc) or unc / diagonal > UNCERTAINTY_OF_DIAGONAL[0] \
            or _relative_std(r) > RELATIVE_STD[0]:
        out.append("The pictures do not pin the camera down yet. Add pictures with the board "
                   "tilted (up to about 45 degrees) towards the left, right, top and bottom, "
                   f"with its {feature} near the image corners and edges, and some closer.")
    if r.coverage < _COVERAGE_ADVICE:
        out.append(f"Only {100 * r.coverage:.0f}% of the image holds points (see the coverage "
                   f"page): move the board so that its {feature} reach the empty (pink) parts.")
    refused = [d for d in r.views_dropped if not d.reason.startswith(NOT_SELECTED)]
    given = len(r.views_used) + len(refused)
    if given and len(r.views_used) / given < USED_SHARE:
        out.append(f"{len(refused)} of {given} pictures could not be used (see the per-view "
                   "page for why): keep the whole board sharp and in view.")
    if board_check and board_check.get("warning"):
        out.append("The printed board does not match its settings: measure it and correct "
                   "the board parameters (see the checks page).")
    if len(r.views_used) < 10 and not r.weak_reason:
        out.append(f"Use more pictures: {len(r.views_used)} were used, 15-20 varied ones "
                   "are recommended.")
    return out


def plain_verdict(result: CalibrationResult, *, board_check: Mapping[str, Any] | None = None,
                  tone_curve: Mapping[str, Any] | None = None,
                  feature: str = "markers") -> PlainVerdict:
    """The first page's words for a calibration (the verdict of
    :func:`~artcal_ros.core.calibrate.verdict.verdict_of`, explained).

    Args:
        result: the calibration.
        board_check, tone_curve: ``summary.json``'s dicts of the same names, if known.
        feature: what the board's features are called (markers, tags, points, circles).
    """
    r = result
    v = verdict_of(r)
    unc = r.projection_uncertainty_rms_px
    meaning = (f"On average the calibrated camera puts each measured board point "
               f"{r.reprojection_rms_px:.2f} pixels from where it was seen (below "
               f"{RMS_PX[0]:g} px is good). From the pictures given, the camera is known well "
               f"enough to place any point of the image within about {unc:.2f} pixels "
               f"(1-sigma; the smaller the better, below "
               f"{UNCERTAINTY_OF_DIAGONAL[0] * np.hypot(*r.image_size):.2f} px is good "
               f"for this image size).")
    actions = _actions(r, board_check, feature)
    headline = _HEADLINES[v.level]
    if v.level == "good" and not actions:
        meaning += " Nothing needs to be done."
    elif v.level == "good":  # the figures are good, but the pictures leave something open
        headline = "GOOD, with reservations: see what to do."
    figures = (
        ("verdict", f"{v.level}: {v.reason}"),
        ("camera", f"{r.model}, {r.image_size[0]} x {r.image_size[1]} px, "
                   f"{r.points} of the board"),
        ("reprojection error", f"RMS {r.reprojection_rms_px:.3f} px, largest "
                               f"{r.reprojection_max_px:.3f} px; hold-out "
                               f"{r.holdout_rms_px:.3f} px"),
        ("projection uncertainty", f"RMS {unc:.3f} px, largest "
                                   f"{r.projection_uncertainty_max_px:.3f} px over the image"),
        ("pictures", f"{len(r.views_used)} used, {len(r.views_dropped)} left out; image "
                     f"coverage {100 * r.coverage:.0f}%"),
    )
    notes = list(r.warnings)
    if board_check and board_check.get("warning"):
        notes.append(f"board check: {board_check['warning']}")
    return PlainVerdict(v.level, headline, meaning, tuple(actions), figures, tuple(notes))


def refused_verdict(reason: str, *, images: int, points: int) -> PlainVerdict:
    """The first page's words for a set that gave no calibration.

    Args:
        reason: why (the CalibrationError's message, which says what to add).
        images: images read; points: board points detected in them.
    """
    return PlainVerdict(
        "refused", "NO CALIBRATION: these pictures cannot give one.",
        f"The pictures were read and the board searched for, but they do not hold what a "
        f"calibration needs. Why: {reason}",
        ("Add the pictures the reason above asks for (the coverage page shows where in the "
         "image the board's points were found so far).",
         "In general: 15-20 sharp pictures of the whole board, tilted in different "
         "directions, covering the whole image, corners included."),
        (("pictures", f"{images} read, {points} board points found"),),
        ())


def intrinsics_rows(result: CalibrationResult) -> list[tuple[str, str, str, str]]:
    """The table of the intrinsics and distortion: (name, value, 1-sigma, unit or note) rows;
    held parameters say ``fixed``."""
    r = result
    K = r.camera_matrix
    values = dict(zip(INTRINSIC_NAMES, (K[0, 0], K[1, 1], K[0, 2], K[1, 2]), strict=True))
    values.update(zip(DIST_NAMES[r.model], r.dist_coeffs, strict=True))
    rows = []
    for name, value in values.items():
        pixel = name in INTRINSIC_NAMES
        text = f"{value:.3f}" if pixel else f"{value:.6g}"
        estimated = name in r.std_devs or (TIED_FOCAL in r.free and name in ("fx", "fy"))
        if estimated and name in r.std_devs:
            s = r.std_devs[name]
            sigma = f"{s:.3f}" if pixel else f"{s:.2g}"
            note = "px" if pixel else ""
            if TIED_FOCAL in r.free and name in ("fx", "fy"):
                note = "px (fx = fy solved as one)"
        else:
            sigma, note = "-", "fixed"
        rows.append((name, text, sigma, note))
    return rows


def dropped_kinds(dropped: Sequence[DroppedView]) -> dict[str, list[DroppedView]]:
    """The views left out grouped by the kind of reason (the reason without its numbers),
    most frequent first."""
    groups: dict[str, list[DroppedView]] = {}
    for d in dropped:
        head = d.reason.split(":")[0] if not d.reason.startswith("after") else d.reason
        kind = re.sub(r"\d+(\.\d+)?", "N", head).strip()[:60]
        groups.setdefault(kind, []).append(d)
    return dict(sorted(groups.items(), key=lambda kv: -len(kv[1])))


def checks_text(tone_curve: Mapping[str, Any] | None,
                board_check: Mapping[str, Any] | None) -> list[str]:
    """The tone-curve and board checks in words, one paragraph each."""
    out = []
    if tone_curve:
        name = tone_curve.get("name") or f"gamma {tone_curve.get('gamma')}"
        how = ("estimated from the images" if tone_curve.get("estimated")
               else "given in the parameters")
        sigma = tone_curve.get("sigma")
        pm = f" (+- {sigma:.2f})" if isinstance(sigma, float) else ""
        sides = tone_curve.get("sides")
        from_edges = f", from {sides} marker edges" if sides else ""
        out.append(f"Tone curve: {name}{pm}, {how}{from_edges}. The detector uses it to find "
                   "the edges of the markers where they really are; a wrong curve moves them "
                   "by a fraction of a pixel. Nothing to do unless it is far from what the "
                   "camera is set to.")
    else:
        out.append("Tone curve: not recorded.")
    if not board_check:
        out.append("Board check: not recorded.")
    elif not board_check.get("views"):
        out.append("Board check: not measured (it needs a marker grid and enough markers per "
                   "picture).")
    elif board_check.get("warning"):
        out.append(f"Board check: the printed board DIFFERS from its settings: "
                   f"{board_check['warning']}")
    else:
        def metres(key: str) -> str:
            value = board_check.get(key) if board_check else None
            return f"{value:.4f} m" if isinstance(value, float) else "?"
        out.append(f"Board check: the printed board matches its settings (gap between "
                   f"markers measured {metres('marker_separation')} with markers of "
                   f"{metres('marker_length')}, from "
                   f"{board_check.get('views')} pictures). A page printed at the wrong scale "
                   "looks the same in every picture: measure one marker with a ruler once.")
    return out
