"""Board self-check: does the printed board match the configured marker length and separation?

Each marker's size against its neighbours' centres (:mod:`artcal_ros.core.detect.edge_shift`)
mixes two things: an optical edge shift (light, blur, the tone curve), a fixed
number of *pixels* in one view, and a print that differs from the configuration,
a fixed fraction of the *marker*. Per view, the markers' relative growth ``y``
against ``x = 2 / (L * px_per_m)`` is a line ``y = g + d x``: its slope ``d`` is the
view's edge shift in pixels and its intercept ``g`` the print's, common to all
views. Views that see markers at different scales (tilted, near and far) pin
``g`` down; the check warns only when ``g`` is both large and well determined, so
a biased detector (markers that look small because every edge moved inward)
does not raise an alarm.

Only the *ratio* of marker length to pitch is observable: a page printed at 97 %
of its size is the same board seen from a little further away, and the
calibration's intrinsics do not change with it (only the translations scale).
The check reports the ratio as a separation, with the marker length as configured.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.camera import CameraModel
from artcal_ros.core.detect.edge_shift import compensate, marker_growth
from artcal_ros.core.detections import Detections

__all__ = ["BoardCheck", "check_board"]

# a separation that differs by less than this share is not worth a warning
_MIN_SEPARATION_CHANGE = 0.02
# nor one the data determine to fewer standard deviations than this
_MIN_SIGMAS = 4.0


@dataclass(frozen=True)
class BoardCheck:
    """The printed board as the images measure it.

    Attributes:
        marker_length: metres (as configured: the scale is not observable).
        marker_separation: metres, measured.
        growth: the print's marker length over the pitch, relative to the configured
            ratio, minus 1; sigma its 1-sigma.
        edge_shift_px: median over the views of the optical edge shift, pixels.
        views: views that measured it.
        warning: empty when the print matches the configuration.
    """

    marker_length: float
    marker_separation: float
    growth: float
    sigma: float
    edge_shift_px: float
    views: int
    warning: str

    def text(self) -> str:
        """One line for a summary or a diagnostic."""
        if not self.views:
            return "not measured (too few markers per view, or not a marker grid)"
        state = "DIFFERS, see the warning" if self.warning else "matches the configuration"
        return (f"{state}: separation {self.marker_separation:.4f} m (marker length "
                f"{self.marker_length:.4f} m, {self.views} views); edge shift "
                f"{self.edge_shift_px:+.3f} px (median of the views, removed from the corners); "
                "a page printed at another scale looks the same in every image: check one "
                "marker's length with a ruler")

    def as_dict(self) -> dict[str, object]:
        """JSON-ready (``marker_length``, ``marker_separation``, ``warning`` and the rest)."""
        def num(v: float, digits: int) -> float | None:
            return round(float(v), digits) if np.isfinite(v) else None
        return {"marker_length": num(self.marker_length, 6),
                "marker_separation": num(self.marker_separation, 6),
                "ratio_change": num(self.growth, 5), "ratio_sigma": num(self.sigma, 5),
                "edge_shift_px": num(self.edge_shift_px, 4), "views": self.views,
                "warning": self.warning}


def _view_line(y: np.ndarray, x: np.ndarray) -> tuple[float, float, float] | None:
    """Intercept, its variance and slope of a robust straight-line fit y = g + d x."""
    ok = np.isfinite(y) & np.isfinite(x)
    y, x = y[ok], x[ok]
    if len(y) < 8 or np.ptp(x) <= 0:
        return None
    for _ in range(2):
        A = np.c_[np.ones_like(x), x]
        coef, *_ = np.linalg.lstsq(A, y, rcond=None)
        r = y - A @ coef
        mad = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        keep = np.abs(r) <= max(4.0 * mad, 1e-6)
        y, x = y[keep], x[keep]
        if len(y) < 8:
            return None
    A = np.c_[np.ones_like(x), x]
    coef, *_ = np.linalg.lstsq(A, y, rcond=None)
    r = y - A @ coef
    var = float(r @ r) / max(len(y) - 2, 1)
    cov = np.linalg.pinv(A.T @ A) * var
    return float(coef[0]), float(cov[0, 0]), float(coef[1])


def check_board(views: Sequence[Detections], board: Board,
                camera: CameraModel | None = None) -> BoardCheck:
    """Measure the print from the views' markers (see the module docstring).

    Args:
        views: detections of one camera; corners with their edge shift removed
            (``edge_shift_px``) are moved back first.
        board: the configured board.
        camera: the calibrated camera: points are undistorted through it first.
    """
    L = board.marker_length
    if board.board_type != "marker_grid":
        # a ChArUco board's markers are not on one pitch, a chessboard has none
        return BoardCheck(L, board.marker_separation, float("nan"), float("nan"),
                          float("nan"), 0, "")
    pitch = L + board.marker_separation
    g_views, w_views, shifts = [], [], []
    for det in views:
        if len(det.ids) < 8:
            continue
        q, c = det.corners_px, det.centers_px
        if camera is not None:
            q = camera.undistort(q.reshape(-1, 2)).reshape(q.shape)
            c = camera.undistort(c)
        if np.isfinite(det.edge_shift_px) and det.edge_shift_px != 0.0:
            q = compensate(q, -det.edge_shift_px)  # the shift the detector removed, back
        growth = marker_growth(det.ids, q, c, board)
        x = 2.0 / (L * growth.px_per_m)
        y = growth.growth
        line = _view_line(y, x)
        if line is None:
            continue
        g_views.append(line[0])
        w_views.append(1.0 / max(line[1], 1e-12))
        shifts.append(line[2])
    if not g_views:
        return BoardCheck(L, board.marker_separation, float("nan"), float("nan"),
                          float("nan"), 0, "")
    g_arr, w_arr = np.asarray(g_views), np.asarray(w_views)
    g = float(np.sum(w_arr * g_arr) / np.sum(w_arr))
    chi2 = float(np.sum(w_arr * (g_arr - g) ** 2)) / max(len(g_arr) - 1, 1)
    sigma = float(np.sqrt(max(chi2, 1.0) / np.sum(w_arr)))
    separation = pitch / (1.0 + g) - L
    change = separation / board.marker_separation - 1.0
    warning = ""
    if abs(change) > _MIN_SEPARATION_CHANGE and abs(g) > _MIN_SIGMAS * sigma:
        scaled_length = L * (1.0 + g)
        warning = (f"the printed board does not match board.marker_length / "
                   f"board.marker_separation: its markers measure {100 * (1 + g):.1f} % of "
                   f"the configured share of the pitch (+- {100 * sigma:.1f} %, "
                   f"{len(g_arr)} views): the separation is {separation:.4f} m, not "
                   f"{board.marker_separation:.4f} m, with the marker length as configured "
                   f"(or the markers are {scaled_length:.4f} m with the pitch as configured); "
                   f"measure the print and set board.marker_separation: {separation:.4f}")
    return BoardCheck(L, separation, g, sigma, float(np.median(shifts)), len(g_arr), warning)
