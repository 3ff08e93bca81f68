"""The text pages of a calibration report: the first page (the verdict in a user's words) and
the numbers page (intrinsics with their standard deviations, the tone-curve and board
checks, the pictures left out)."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping
from typing import Any

from matplotlib.figure import Figure

from artcal_ros.core.calibrate.report_plots import (
    BLUE,
    RED,
    draw_coverage,
    draw_uncertainty,
    image_axes,
    page,
)
from artcal_ros.core.calibrate.report_text import (
    PlainVerdict,
    checks_text,
    dropped_kinds,
    intrinsics_rows,
)
from artcal_ros.core.calibrate.result import CalibrationResult

LEVEL_COLOURS = {"good": "#2a8a3e", "usable": "#d08a00", "poor": RED, "refused": RED}
_WRAP = 118  # characters per line of body text on a page
_NARROW = 84  # the same beside the first page's maps


def _wrapped(text: str, width: int = _WRAP, indent: str = "") -> str:
    return textwrap.fill(text, width, initial_indent=indent,
                         subsequent_indent=" " * len(indent))


def verdict_page(verdict: PlainVerdict, title: str,
                 result: CalibrationResult | None = None) -> Figure:
    """The first page: the verdict in large type, what it means, what to do, the key figures
    and the solver's notes; with ``result``, small maps of the coverage and the uncertainty
    in a column on the right."""
    fig = page(title)
    colour = LEVEL_COLOURS.get(verdict.level, "black")
    fig.text(0.04, 0.88, verdict.headline, fontsize=18, fontweight="bold", color=colour,
             va="top")
    wrap = _WRAP if result is None else _NARROW  # the maps take the right third
    y = 0.81
    body: list[tuple[str, float, str, str]] = [(_wrapped(verdict.meaning, wrap), 11,
                                                 "normal", "black")]
    if verdict.actions:
        body.append(("What to do:", 12, "bold", "black"))
        body += [(_wrapped(a, wrap - 4, "-  "), 10.5, "normal", "black")
                 for a in verdict.actions]
    body.append(("The figures:", 12, "bold", "black"))
    body += [(_wrapped(f"{k}: {v}", wrap + 8, "   "), 9.5, "normal", "#222")
             for k, v in verdict.figures]
    if verdict.notes:
        body.append(("Notes from the solver and the checks:", 12, "bold", "black"))
        body += [(_wrapped(n, wrap + 8, "-  "), 9, "normal", "#444") for n in verdict.notes]
    for text, size, weight, col in body:
        if y < 0.04:
            break
        fig.text(0.04, y, text, fontsize=size, fontweight=weight, color=col, va="top")
        lines = text.count("\n") + 1
        y -= (lines * size * 1.45 + 7) / (72.0 * fig.get_figheight())
    if result is not None:
        _thumbnails(fig, result)
    return fig


def _thumbnails(fig: Figure, result: CalibrationResult) -> None:
    """The coverage and the uncertainty map, small, one above the other on the right."""
    w, h = result.image_size
    width = 0.27
    height = min(width * fig.get_figwidth() / fig.get_figheight() * h / w, 0.34)
    top = image_axes(fig, result.image_size, (0.69, 0.86 - height, width, height))
    draw_coverage(top, result.image_size, result.points_px, dot=0.6)
    top.set_title(f"where the points are: {100 * result.coverage:.0f}% covered\n"
                  "(pink cells: none)", fontsize=9)
    low = image_axes(fig, result.image_size, (0.69, 0.42 - height, width, height))
    if draw_uncertainty(fig, low, result, colorbar=False):
        low.set_title(f"how well the camera is known (1-sigma, px):\nRMS "
                      f"{result.projection_uncertainty_rms_px:.3f} px; contours labelled",
                      fontsize=9)
    for ax in (top, low):
        ax.tick_params(labelsize=7)
        ax.set_xlabel("")
        ax.set_ylabel("")


def numbers_page(result: CalibrationResult, tone_curve: Mapping[str, Any] | None,
                 board_check: Mapping[str, Any] | None) -> Figure:
    """The intrinsics and distortion with their 1-sigma (a table), the tone-curve and board
    checks in words and the pictures left out, grouped by why."""
    fig = page("The numbers: intrinsics, checks, pictures left out",
               "1-sigma: the standard deviation of each value from the pictures given (a 68 % "
               "chance that the true value is within it). 'fixed': held, not solved.")
    ax = fig.add_axes((0.04, 0.38, 0.42, 0.52))
    ax.axis("off")
    rows = intrinsics_rows(result)
    table = ax.table(cellText=[list(r) for r in rows],
                     colLabels=["parameter", "value", "1-sigma", ""], loc="upper left",
                     colLoc="left", cellLoc="left", colWidths=[0.2, 0.3, 0.2, 0.4])
    table.auto_set_font_size(False)
    table.set_fontsize(9)
    table.scale(1.0, 1.25)
    for (row, _col), cell in table.get_celld().items():
        cell.set_edgecolor("#cccccc")
        if row == 0:
            cell.set_text_props(fontweight="bold")
    r = result
    figures = [f"reprojection error: RMS {r.reprojection_rms_px:.4f} px, std "
               f"{r.reprojection_std_px:.4f} px, largest {r.reprojection_max_px:.4f} px",
               f"hold-out error (each picture checked against a camera solved without it): "
               f"RMS {r.holdout_rms_px:.4f} px",
               f"projection uncertainty: RMS {r.projection_uncertainty_rms_px:.4f} px, largest "
               f"{r.projection_uncertainty_max_px:.4f} px",
               f"{len(r.points_px)} points used, {r.points_dropped} outlier points left out; "
               f"solved in {r.solve_time_s:.1f} s"]
    below = 0.88 - (len(rows) + 1) * 0.029 - 0.03  # under the table
    fig.text(0.04, below, "\n".join(_wrapped(f, 70) for f in figures), fontsize=9, va="top")
    y = 0.90
    fig.text(0.52, y, "Checks", fontsize=12, fontweight="bold", va="top")
    y -= 0.045
    for para in checks_text(tone_curve, board_check):
        text = _wrapped(para, 62)
        fig.text(0.52, y, text, fontsize=9, va="top")
        y -= (text.count("\n") + 1) * 0.022 + 0.02
    fig.text(0.52, y, "Pictures left out", fontsize=12, fontweight="bold", va="top")
    y -= 0.045
    kinds = dropped_kinds(r.views_dropped)
    if not kinds:
        fig.text(0.52, y, "none", fontsize=9, va="top")
    for kind, views in list(kinds.items())[:6]:
        listed = ", ".join(f"#{d.view_index}" for d in views[:12])
        more = f" and {len(views) - 12} more" if len(views) > 12 else ""
        text = _wrapped(f"{len(views)} x {kind}: {listed}{more}", 62)
        fig.text(0.52, y, text, fontsize=9, va="top", color=BLUE)
        y -= (text.count("\n") + 1) * 0.022 + 0.015
        if y < 0.1:
            break
    return fig

