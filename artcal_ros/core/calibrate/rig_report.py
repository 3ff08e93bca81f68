"""The report page of each rectified pair of a rig, drawn with OpenCV.

``pair_<a>_<b>.png``, top to bottom:

- the rig from above: every camera's centre and optical axis in the reference camera's
  frame (x to the right, z up the page), and where the board's centre was in the frames
  used (grey dots);
- the residual vectors of camera a and of camera b over their images (the joint solve's);
- the epipolar error after rectification: for every board point both cameras measure in a
  frame, the row difference of its two rectified images (the column difference for a
  vertical pair), against its position along the rectified image.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.rectify import rectified_points
from artcal_ros.core.calibrate.report import residual_plot
from artcal_ros.core.calibrate.rig_result import Pair, RigResult
from artcal_ros.core.calibrate.views import view_points
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError

_FONT = cv2.FONT_HERSHEY_SIMPLEX
_BLACK = (0, 0, 0)
_GREY = (170, 170, 170)
_BLUE = (180, 90, 20)
_RED = (30, 30, 220)
_WIDTH = 980


def _title(canvas: np.ndarray, text: str) -> None:
    cv2.putText(canvas, text, (10, 25), _FONT, 0.6, _BLACK, 1, cv2.LINE_AA)


def _board_centres(rig: RigResult, board: Board) -> np.ndarray:
    """(F, 3) the board's centre in the reference camera's frame, each frame used, metres."""
    x0, y0, x1, y1 = board.extent_m
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    out = [cv2.Rodrigues(np.asarray(r, np.float64).reshape(3, 1))[0] @ centre + t
           for r, t in zip(np.asarray(rig.board_rvecs).reshape(-1, 3),
                           np.asarray(rig.board_tvecs, np.float64).reshape(-1, 3), strict=True)]
    return np.array(out).reshape(-1, 3)


def geometry_plot(rig: RigResult, pair: Pair, board: Board, height: int = 440) -> np.ndarray:
    """BGR image of the rig from above (x right, z up), the pair's cameras in blue."""
    canvas = np.full((height, _WIDTH, 3), 255, np.uint8)
    centres, axes = {}, {}
    for n in rig.names:
        R, t = rig.extrinsics[rig.reference, n] if n != rig.reference else (np.eye(3),
                                                                            np.zeros(3))
        centres[n] = -R.T @ t               # the camera's centre in the reference frame
        axes[n] = R.T @ np.array([0.0, 0.0, 1.0])
    boards = _board_centres(rig, board)
    xz = np.array([[c[0], c[2]] for c in centres.values()])
    spread = max(float(np.ptp(xz[:, 0])), float(np.ptp(xz[:, 1])), 0.05)
    reach = spread * 1.5                     # axis length drawn, metres
    pts = np.vstack([xz, xz + reach * np.array([[a[0], a[2]] for a in axes.values()]),
                     boards[:, [0, 2]] if len(boards) else np.zeros((0, 2))])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    scale = min((_WIDTH - 80) / max(hi[0] - lo[0], 1e-6),
                (height - 110) / max(hi[1] - lo[1], 1e-6))
    left = (_WIDTH - (hi[0] - lo[0]) * scale) / 2   # centred across the page

    def at(x: float, z: float) -> tuple[int, int]:
        return (round(left + (x - lo[0]) * scale), round(height - 30 - (z - lo[1]) * scale))

    for b in boards:
        cv2.circle(canvas, at(b[0], b[2]), 3, _GREY, -1)
    for k, n in enumerate(rig.names):
        c, a = centres[n], axes[n]
        colour = _BLUE if n in pair else _BLACK
        cv2.arrowedLine(canvas, at(c[0], c[2]), at(c[0] + reach * a[0], c[2] + reach * a[2]),
                        colour, 2, cv2.LINE_AA, tipLength=0.06)
        cv2.circle(canvas, at(c[0], c[2]), 5, colour, -1)
        x, y = at(c[0], c[2])
        width = cv2.getTextSize(n, _FONT, 0.5, 1)[0][0]
        # names alternate left and right of their cameras, so neighbours' do not overlap
        cv2.putText(canvas, n, (x - 10 - width if k % 2 == 0 else x + 10, y + 5), _FONT, 0.5,
                    colour, 1, cv2.LINE_AA)
    p = rig.pairs[pair]
    _title(canvas, "the rig from above (x right, z forward; grey: the board's centre in each "
                   "frame used)")
    cv2.putText(canvas, f"{pair[0]} -> {pair[1]}: baseline {p.baseline_m:.6f} m +- "
                        f"{p.baseline_std_m * 1000:.3f} mm, rotation {p.rotation_deg:.3f} deg, "
                        f"{p.shared_frames} shared frames", (10, 50), _FONT, 0.5, _BLACK, 1,
                cv2.LINE_AA)
    return canvas


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


def epipolar_plot(rig: RigResult, pair: Pair, along: np.ndarray, error: np.ndarray,
                  height: int = 300) -> np.ndarray:
    """BGR image of the epipolar errors against the position along the rectified image."""
    canvas = np.full((height, _WIDTH, 3), 255, np.uint8)
    rect = rig.rectification[pair]
    size = rect.image_sizes[0][1 if rect.vertical else 0]
    left, right, top, bottom = 60, _WIDTH - 20, 45, height - 30
    lim = max(float(np.percentile(np.abs(error), 99)) * 1.2 if len(error) else 0.0, 0.05)
    mid = (top + bottom) // 2
    cv2.rectangle(canvas, (left, top), (right, bottom), _BLACK, 1)
    cv2.line(canvas, (left, mid), (right, mid), _GREY, 1)
    for x, e in zip(along, error, strict=True):
        u = round(left + np.clip(x / max(size, 1), 0, 1) * (right - left))
        v = round(mid - np.clip(e / lim, -1, 1) * (bottom - top) / 2)
        cv2.circle(canvas, (u, v), 1, _RED if abs(e) >= lim else _BLUE, -1)
    for frac, label in ((0.0, f"+{lim:.2f}"), (1.0, f"-{lim:.2f}")):
        cv2.putText(canvas, label, (5, round(top + frac * (bottom - top)) + 5), _FONT, 0.4,
                    _BLACK, 1, cv2.LINE_AA)
    what = "column" if rect.vertical else "row"
    rms = float(np.sqrt(np.mean(error ** 2))) if len(error) else float("nan")
    _title(canvas, f"epipolar error after rectification ({what} difference, px): RMS "
                   f"{rms:.3f} px over {len(error)} points")
    cv2.putText(canvas, f"position along the rectified image, 0..{size} px", (left, height - 8),
                _FONT, 0.45, _BLACK, 1, cv2.LINE_AA)
    return canvas


def pair_page(rig: RigResult, pair: Pair,
              detections: Mapping[str, Sequence[Detections | None]], board: Board,
              points: str) -> np.ndarray:
    """The whole page of one pair (see the module docstring), BGR."""
    half = []
    for n in pair:
        plot = residual_plot(rig.cameras[n])
        scale = (_WIDTH // 2) / plot.shape[1]
        small = cv2.resize(plot, (_WIDTH // 2, round(plot.shape[0] * scale)),
                           interpolation=cv2.INTER_AREA)
        cv2.putText(small, n, (12, small.shape[0] - 10), _FONT, 0.6, _BLUE, 1, cv2.LINE_AA)
        half.append(small)
    h = max(p.shape[0] for p in half)
    row = np.full((h, _WIDTH, 3), 255, np.uint8)
    row[:half[0].shape[0], :_WIDTH // 2] = half[0]
    row[:half[1].shape[0], _WIDTH // 2:_WIDTH // 2 + half[1].shape[1]] = half[1]
    along, error = epipolar_errors(rig, pair, detections, board, points)
    return np.vstack([geometry_plot(rig, pair, board), row,
                      epipolar_plot(rig, pair, along, error)])


def write_pair_pages(directory: Path, rig: RigResult,
                     detections: Mapping[str, Sequence[Detections | None]], board: Board,
                     points: str) -> list[Path]:
    """Write ``pair_<a>_<b>.png`` of each rectified pair into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for pair in rig.rectification:
        path = directory / f"pair_{pair[0]}_{pair[1]}.png"
        if not cv2.imwrite(str(path), pair_page(rig, pair, detections, board, points)):
            raise ArtcalError(f"cannot write {path}")
        out.append(path)
    return out
