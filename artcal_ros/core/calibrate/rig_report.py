"""The report of a rig: report.pdf with the rig's first page, a page per rectified pair and
each camera's pages, and each page as a PNG.

Pages, in order (PNG in brackets): the rig's verdict in words (``verdict.png``); for each
rectified pair (``pair_<a>_<b>.png``): the rig from above (every camera's centre and optical
axis in the reference camera's frame, x to the right, z up the page, and the board's centre in
the frames used), the residual vectors of camera a and of camera b over their images (the
joint solve's), and the epipolar error after rectification (for every board point both
cameras measure in a frame, the row difference of its two rectified images, the column
difference for a vertical pair, against its position along the rectified image); then each
camera's pages as one camera's report has them, but for the first, which the rig's covers
(``<name>/*.png``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from matplotlib.figure import Figure

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.rectify import rectified_points
from artcal_ros.core.calibrate.report import PdfReport, calibration_pages, write_summary
from artcal_ros.core.calibrate.report_pages import verdict_page
from artcal_ros.core.calibrate.report_plots import (
    BLUE,
    GREY,
    RED,
    draw_residuals,
    image_axes,
    page,
    residual_gain,
)
from artcal_ros.core.calibrate.report_text import PlainVerdict, plain_verdict
from artcal_ros.core.calibrate.rig_result import Pair, RigResult
from artcal_ros.core.calibrate.verdict import LEVELS
from artcal_ros.core.calibrate.views import feature_term, view_points
from artcal_ros.core.detections import Detections

__all__ = ["epipolar_errors", "pair_page", "rig_verdict_words", "write_rig_report"]

# rectified epipolar RMS at or below which a pair is good, px (rows agree to a fraction of a
# pixel: stereo matching along rows works)
EPIPOLAR_GOOD_PX = 0.5


def _board_centres(rig: RigResult, board: Board) -> np.ndarray:
    """(F, 3) the board's centre in the reference camera's frame, each frame used, metres."""
    x0, y0, x1, y1 = board.extent_m
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    out = [cv2.Rodrigues(np.asarray(r, np.float64).reshape(3, 1))[0] @ centre + t
           for r, t in zip(np.asarray(rig.board_rvecs).reshape(-1, 3),
                           np.asarray(rig.board_tvecs, np.float64).reshape(-1, 3), strict=True)]
    return np.array(out).reshape(-1, 3)


def epipolar_errors(rig: RigResult, pair: Pair,
                    detections: Mapping[str, Sequence[Detections | None]], board: Board,
                    points: str) -> tuple[np.ndarray, np.ndarray]:
    """(position along the rectified image (N,), epipolar error (N,)) in pixels, of every
    board point cameras a and b both measure in a frame of ``rig.frames_used``."""
    a, b = pair
    rect = rig.rectification[pair]
    along, error = [], []
    for f in rig.frames_used:
        da, db = detections[a][f], detections[b][f]
        if da is None or db is None or not len(da.ids) + len(da.point_ids) or \
                not len(db.ids) + len(db.point_ids):
            continue
        va, vb = view_points(da, board, points, f), view_points(db, board, points, f)
        key_b = {tuple(np.round(p, 9)): i for i, p in enumerate(vb.object_points)}
        ia, ib = [], []
        for i, p in enumerate(va.object_points):
            j = key_b.get(tuple(np.round(p, 9)))
            if j is not None:
                ia.append(i)
                ib.append(j)
        if not ia:
            continue
        ra = rectified_points(rig.cameras[a].camera, rect.R1, rect.P1, va.image_points[ia])
        rb = rectified_points(rig.cameras[b].camera, rect.R2, rect.P2, vb.image_points[ib])
        k = 0 if rect.vertical else 1
        along.append(ra[:, 1 - k])
        error.append(ra[:, k] - rb[:, k])
    if not along:
        return np.zeros(0), np.zeros(0)
    x, e = np.concatenate(along), np.concatenate(error)
    ok = np.isfinite(x) & np.isfinite(e)
    return x[ok], e[ok]


def _geometry(ax: Any, rig: RigResult, pair: Pair, board: Board) -> None:
    """The rig from above (x right, z up the page), the pair's cameras in blue."""
    centres, axes = {}, {}
    for n in rig.names:
        R, t = rig.extrinsics[rig.reference, n] if n != rig.reference else (np.eye(3),
                                                                            np.zeros(3))
        centres[n] = -R.T @ t               # the camera's centre in the reference frame
        axes[n] = R.T @ np.array([0.0, 0.0, 1.0])
    boards = _board_centres(rig, board)
    xz = np.array([[c[0], c[2]] for c in centres.values()])
    reach = max(float(np.ptp(xz[:, 0])), float(np.ptp(xz[:, 1])), 0.05) * 1.5
    if len(boards):  # axes long enough to see beside the boards' distance
        reach = max(reach, 0.15 * float(np.max(np.abs(boards[:, 2]))))
    if len(boards):
        ax.plot(boards[:, 0], boards[:, 2], ".", color=GREY, ms=4,
                label="board centre, each frame used")
    for k, n in enumerate(rig.names):
        c, a = centres[n], axes[n]
        colour = BLUE if n in pair else "black"
        ax.annotate("", xy=(c[0] + reach * a[0], c[2] + reach * a[2]), xytext=(c[0], c[2]),
                    arrowprops={"arrowstyle": "->", "color": colour, "lw": 1.5})
        ax.plot(c[0], c[2], "o", color=colour, ms=6)
        ax.annotate(n, (c[0], c[2]), textcoords="offset points",
                    xytext=(-8 if k % 2 == 0 else 8, -4), ha="right" if k % 2 == 0 else "left",
                    color=colour, fontsize=9)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m, reference camera's frame)")
    ax.set_ylabel("z, forward (m)")
    ax.legend(fontsize=7, loc="lower right")
    ax.set_title("the rig from above", fontsize=10)


def pair_page(rig: RigResult, pair: Pair,
              detections: Mapping[str, Sequence[Detections | None]], board: Board,
              points: str) -> Figure:
    """The page of one rectified pair (see the module docstring)."""
    a, b = pair
    p = rig.pairs[pair]
    rect = rig.rectification[pair]
    fig = page(f"Pair {a} -> {b}: baseline {p.baseline_m:.4f} m +- "
               f"{p.baseline_std_m * 1000:.2g} mm, rotation {p.rotation_deg:.2f} deg, "
               f"{p.shared_frames} shared frames",
               "Left: where the cameras are (blue: this pair). Middle: each camera's residuals "
               "in the joint solve, magnified. Bottom: after rectification the same "
               "board point should land on the same row in both images; the dots are how far "
               f"apart they land (px). Below {EPIPOLAR_GOOD_PX:g} px RMS is good for stereo "
               "matching; a tilt or a spread growing to one side means the pair's rotation is "
               "off, large scatter often means images that were not taken at the same instant.")
    _geometry(fig.add_axes((0.05, 0.50, 0.27, 0.38)), rig, pair, board)
    for k, n in enumerate(pair):
        res = rig.cameras[n]
        ax = image_axes(fig, res.image_size, (0.37 + k * 0.32, 0.50, 0.28, 0.38))
        gain = residual_gain(res.residuals_px, res.image_size, share=0.08)  # a small panel
        draw_residuals(ax, res, gain)
        ax.set_title(f"{n}: residuals x{gain:g}, RMS {res.reprojection_rms_px:.3f} px",
                     fontsize=10)
        ax.tick_params(labelsize=7)
        ax.xaxis.label.set_fontsize(8)
        ax.yaxis.label.set_fontsize(8)
    along, error = epipolar_errors(rig, pair, detections, board, points)
    ax = fig.add_axes((0.07, 0.14, 0.88, 0.27))
    size = rect.image_sizes[0][1 if rect.vertical else 0]
    lim = max(float(np.percentile(np.abs(error), 99.5)) * 1.2 if len(error) else 0.0, 0.05)
    ax.plot(along, np.clip(error, -lim, lim), ".", ms=1.5, color=BLUE, rasterized=True)
    ax.axhline(0.0, color=GREY, lw=0.8)
    ax.set_xlim(0, size)
    ax.set_ylim(-lim, lim)
    what = "column" if rect.vertical else "row"
    rms = float(np.sqrt(np.mean(error ** 2))) if len(error) else float("nan")
    ax.set_title(f"epipolar error after rectification ({what} difference): RMS {rms:.3f} px "
                 f"over {len(error)} points", fontsize=10, color=RED if rms > EPIPOLAR_GOOD_PX
                 else "black")
    ax.set_xlabel("position along the rectified image (px)")
    ax.set_ylabel(f"{what} difference (px)")
    return fig


def rig_verdict_words(rig: RigResult, board: Board | None = None,
                      checks: Mapping[str, Mapping[str, Any]] | None = None) -> PlainVerdict:
    """The rig's first page in words: the worst of its cameras' verdicts and of its pairs'
    epipolar errors, what to do, each camera's and pair's figures and the rig's warnings.

    Args:
        checks: camera name -> its ``tone_curve`` and ``board_check`` dicts, if known.
    """
    feature = feature_term(board) if board is not None else "markers"
    per_camera = {n: plain_verdict(rig.cameras[n], feature=feature,
                                   board_check=(checks or {}).get(n, {}).get("board_check"))
                  for n in rig.names}
    level = max((v.level for v in per_camera.values()), key=LEVELS.index)
    epi = rig.rectified_epipolar_rms_px
    bad_pairs = [f"{a}-{b}" for (a, b), e in epi.items()
                 if not np.isfinite(e) or e > EPIPOLAR_GOOD_PX]
    actions = []
    if bad_pairs:
        level = max(level, "usable", key=LEVELS.index)
        actions.append(f"After rectification the rows of {', '.join(bad_pairs)} differ by more "
                       f"than {EPIPOLAR_GOOD_PX:g} px: check that the cameras take their "
                       "pictures at the same instant (their time stamps, sync_tolerance) and "
                       "did not move against each other during the recording.")
    for n, v in per_camera.items():
        actions += [f"{n}: {a}" for a in v.actions]
    headline = {"good": "GOOD: this rig calibration can be used.",
                "usable": "USABLE: it works, but could be better.",
                "poor": "POOR: do not rely on it yet."}[level]
    listed = [(rig.reference, n) for n in rig.names[1:]]
    listed += [p for p in rig.consecutive_pairs if p not in listed]
    figures = [(f"camera {n}", v.figures[0][1]) for n, v in per_camera.items()]
    for a, b in listed:
        p = rig.pairs[a, b]
        text = (f"baseline {p.baseline_m:.5f} m +- {p.baseline_std_m * 1000:.3f} mm, rotation "
                f"{p.rotation_deg:.3f} deg, {p.shared_frames} shared frames")
        if (a, b) in epi:
            text += f", rectified epipolar RMS {epi[a, b]:.3f} px"
        figures.append((f"{a} -> {b}", text))
    meaning = (f"{len(rig.names)} cameras ({', '.join(rig.names)}) solved together from "
               f"{len(rig.frames_used)} frames; the points fit to {rig.reprojection_rms_px:.3f} "
               "px RMS over all cameras. The pages after this one show each pair (where the "
               "cameras are and how well their images line up after rectification) and each "
               "camera as a single camera's report does.")
    notes = list(rig.warnings) + [f"{n}: {w}" for n, v in per_camera.items() for w in v.notes]
    return PlainVerdict(level, headline, meaning, tuple(actions), tuple(figures), tuple(notes))


def write_rig_report(directory: str | Path, rig: RigResult,
                     detections: Mapping[str, Sequence[Detections | None]], board: Board,
                     points: str, *, checks: Mapping[str, Mapping[str, Any]] | None = None,
                     summary: Mapping[str, Any] | None = None,
                     progress: Callable[[str], None] | None = None) -> list[Path]:
    """Write a rig's report.pdf and its pages' PNGs into ``directory`` (the module
    docstring lists them) and, given, ``summary`` as summary.json.

    Args:
        detections: camera -> the rig's frames (index = frame, as ``calibrate_rig`` got them).
        points: the ``points`` parameter the rig was solved with.
        checks: camera -> ``{"tone_curve": ..., "board_check": ...}`` dicts, if known.
        summary: the summary.json content (``rig.to_summary_dict()`` and what the caller
            adds); None writes none.
        progress: told each page group as it is drawn.

    Returns:
        The files written, report.pdf first.
    """
    say = progress or (lambda _msg: None)
    report = PdfReport(directory)
    report.add(verdict_page(rig_verdict_words(rig, board, checks),
                            f"Rig calibration report: {', '.join(rig.names)}"), "verdict.png")
    for pair in rig.rectification:
        say(f"report: pair {pair[0]}-{pair[1]}")
        report.add(pair_page(rig, pair, detections, board, points),
                   f"pair_{pair[0]}_{pair[1]}.png")
    for n in rig.names:
        say(f"report: camera {n}")
        cam_checks = (checks or {}).get(n, {})
        for png, fig in calibration_pages(rig.cameras[n], title=f"camera {n}", first_page=False,
                                          tone_curve=cam_checks.get("tone_curve"),
                                          board_check=cam_checks.get("board_check"),
                                          detections=detections[n],
                                          board=board):
            report.add(fig, f"{n}/{png}")
    written = report.close()
    if summary is not None:
        written.append(write_summary(Path(directory).expanduser(), summary))
    return written

