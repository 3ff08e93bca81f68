"""The plots of a calibration report, each one matplotlib figure (one page of report.pdf, one
PNG).

Drawn through matplotlib's object interface (``Figure``, no pyplot): no display, no global
backend state, safe in the node's solve thread. Image plots use OpenCV's pixel convention
(the centre of the top-left pixel is (0, 0), y down).
"""

from __future__ import annotations

import textwrap
from collections.abc import Mapping

import numpy as np
from matplotlib.axes import Axes
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import MaxNLocator

from artcal_ros.core.calibrate.model import Solution
from artcal_ros.core.calibrate.quality import solution_camera, uncertainty_map
from artcal_ros.core.calibrate.report_text import dropped_kinds
from artcal_ros.core.calibrate.result import CalibrationResult
from artcal_ros.core.calibrate.views import COVERAGE_GRID
from artcal_ros.core.camera import CameraModel

PAGE_INCHES = (11.0, 7.5)  # landscape, fits A4 and US letter
BLUE, RED, GREY = "#1f5fa8", "#c8281e", "#9a9a9a"
_EXPLAIN_Y = 0.012  # where a page's explanation line sits, figure fraction
MAX_ARROWS = 4000  # residual arrows drawn at most (an even subset): more only blacken the page


def page(title: str, explain: str = "") -> Figure:
    """An empty report page with its title and, at the bottom, what it shows in words."""
    fig = Figure(figsize=PAGE_INCHES)
    fig.suptitle(title, fontsize=14, fontweight="bold", x=0.04, ha="left", y=0.97)
    if explain:  # wrapped by characters: matplotlib's own wrapping measures every word
        fig.text(0.04, _EXPLAIN_Y, textwrap.fill(explain, 150), fontsize=9, va="bottom",
                 color="#333")
    return fig


def image_axes(fig: Figure, image_size: tuple[int, int],
               rect: tuple[float, float, float, float] = (0.06, 0.15, 0.78, 0.75)) -> Axes:
    """Axes showing the image frame, pixels, y down."""
    w, h = image_size
    ax = fig.add_axes(rect)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x (px)")
    ax.set_ylabel("y (px)")
    return ax


def solution_of(result: CalibrationResult) -> Solution:
    """The result as a :class:`Solution` (its camera, poses and free parameters)."""
    return Solution(result.camera_matrix, result.dist_coeffs, result.model, result.rvecs,
                    result.tvecs, result.free)


def residual_gain(residuals_px: np.ndarray, image_size: tuple[int, int],
                  share: float = 0.03) -> float:
    """The magnification of the residual arrows: the 95th percentile length draws ``share``
    of the image width, rounded down to 1, 2 or 5 times a power of ten."""
    norms = np.linalg.norm(np.asarray(residuals_px).reshape(-1, 2), axis=1)
    norms = norms[np.isfinite(norms)]
    ref = float(np.percentile(norms, 95)) if len(norms) else 1.0
    raw = share * image_size[0] / max(ref, 1e-6)
    decade = 10.0 ** np.floor(np.log10(raw))
    return float(max(m for m in (1.0, 2.0, 5.0) if m * decade <= raw) * decade)


def draw_residuals(ax: Axes, result: CalibrationResult, gain: float) -> int:
    """The residual vectors of ``result`` on ``ax`` (image axes), magnified ``gain`` times,
    with a scale arrow; outliers left out as red crosses. Returns the arrows drawn (at most
    :data:`MAX_ARROWS`, an even subset)."""
    step = int(np.ceil(len(result.points_px) / MAX_ARROWS)) if len(result.points_px) else 1
    p, r = result.points_px[::step], result.residuals_px[::step]
    segments = np.stack([p, p + gain * r], axis=1)
    ax.add_collection(LineCollection(list(segments), colors=BLUE, linewidths=0.7,
                                     rasterized=True))
    ax.plot(p[:, 0], p[:, 1], ".", ms=0.8, color="black", rasterized=True)
    if len(result.outliers_px):
        ax.plot(result.outliers_px[:, 0], result.outliers_px[:, 1], "x", color=RED, ms=5,
                label=f"{len(result.outliers_px)} outliers left out")
        ax.legend(loc="upper right", fontsize=8)
    # a scale arrow of a round length in the lower-left corner
    w, h = result.image_size
    length = _round_down(0.08 * w / gain)
    x0, y0 = 0.04 * w, 0.95 * h
    ax.annotate("", xy=(x0 + gain * length, y0), xytext=(x0, y0),
                arrowprops={"arrowstyle": "->", "color": RED, "lw": 1.5})
    ax.text(x0, y0 - 0.02 * h, f"{length:g} px", color=RED, fontsize=9)
    return len(p)


def _round_down(v: float) -> float:
    decade = 10.0 ** np.floor(np.log10(max(v, 1e-12)))
    return float(max(m for m in (1.0, 2.0, 5.0) if m * decade <= v * (1 + 1e-9)) * decade)


def residual_figure(result: CalibrationResult) -> Figure:
    """Every point's residual (measured minus projected) as an arrow over the image."""
    gain = residual_gain(result.residuals_px, result.image_size)
    fig = page(f"Residuals over the image (arrows magnified {gain:g} times)",
               "Each arrow goes from where a board point was seen towards where the camera "
               "model would need it to be, magnified; the red arrow is the scale. Arrows of "
               "random direction and length are noise (good); arrows that line up, grow "
               "towards the edges or swirl show a lens the model does not describe or a board "
               "that is not flat.")
    ax = image_axes(fig, result.image_size)
    drawn = draw_residuals(ax, result, gain)
    shown = f"{len(result.points_px)} points" + (
        f" (every {len(result.points_px) // drawn}th drawn)" if drawn < len(result.points_px)
        else "")
    ax.set_title(f"RMS {result.reprojection_rms_px:.3f} px, largest "
                 f"{result.reprojection_max_px:.3f} px, {shown}", fontsize=10)
    return fig


def histogram_figure(kinds: Mapping[str, np.ndarray]) -> Figure:
    """The residual components of each point type, ``label -> (N, 2)`` residuals, pixels."""
    fig = page("Residual histogram per point type",
               "How far each point's measured position is from the model's, along x and y. "
               "A narrow bell centred on 0 is good; a wide one means noisy points, a shifted "
               "one a bias. The first panel is the points the camera was solved from; another "
               "type, if shown, is checked with the same camera and board poses.")
    n = max(len(kinds), 1)
    for k, (label, res) in enumerate(kinds.items()):
        ax = fig.add_axes((0.07 + k * 0.9 / n, 0.16, 0.9 / n - 0.07, 0.68))
        res = np.asarray(res, np.float64).reshape(-1, 2)
        res = res[np.all(np.isfinite(res), axis=1)]
        if not len(res):
            ax.text(0.5, 0.5, "no points", ha="center", transform=ax.transAxes)
            continue
        lim = max(float(np.percentile(np.abs(res), 99.5)) * 1.1, 1e-3)
        bins = [float(b) for b in np.linspace(-lim, lim, 61)]
        ax.hist(np.clip(res[:, 0], -lim, lim), bins=bins, histtype="step", color=BLUE,
                label="x", lw=1.3)
        ax.hist(np.clip(res[:, 1], -lim, lim), bins=bins, histtype="step", color=RED,
                label="y", lw=1.3)
        rms = float(np.sqrt(np.mean(np.sum(res ** 2, axis=1))))
        ax.set_title(f"{label}\n{len(res)} points, RMS {rms:.3f} px, mean "
                     f"({res[:, 0].mean():+.3f}, {res[:, 1].mean():+.3f}) px", fontsize=10)
        ax.set_xlabel("residual (px)")
        ax.set_ylabel("points")
        ax.legend(fontsize=8)
    return fig


def _grid_image(pix: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                               np.ndarray]:
    """(xs, ys, (len(ys), len(xs)) values) of grid points, NaN where none."""
    xs, ix = np.unique(pix[:, 0], return_inverse=True)
    ys, iy = np.unique(pix[:, 1], return_inverse=True)
    grid = np.full((len(ys), len(xs)), np.nan)
    grid[iy, ix] = values
    return xs, ys, grid


def _contours(ax: Axes, xs: np.ndarray, ys: np.ndarray, grid: np.ndarray, unit: str) -> None:
    finite = grid[np.isfinite(grid)]
    if len(finite) < 4 or np.ptp(finite) <= 0:
        return
    lo, hi = float(finite.min()), float(finite.max())
    levels = [v for v in MaxNLocator(6).tick_values(lo, hi) if lo < v < hi]
    if not levels:
        return
    cs = ax.contour(xs, ys, grid, levels=levels, colors="white", linewidths=0.9)
    ax.clabel(cs, fmt=lambda v: f"{v:g} {unit}", fontsize=8)


def draw_uncertainty(fig: Figure, ax: Axes, result: CalibrationResult, *,
                     colorbar: bool = True) -> bool:
    """The 1-sigma projection uncertainty map of ``result`` on ``ax`` (image axes), with
    contours; False when the result has no covariance."""
    cov = np.asarray(result.covariance, np.float64)
    step = max(result.image_size) / 60.0
    pix, sigma = (uncertainty_map(solution_of(result), result.image_size, cov, step_px=step)
                  if cov.size and cov.shape[0] == len(result.free) else (np.zeros((0, 2)),
                                                                          np.zeros(0)))
    if not len(pix):
        ax.text(0.5, 0.5, "no covariance recorded", ha="center", transform=ax.transAxes)
        return False
    xs, ys, grid = _grid_image(pix, sigma)
    im = ax.pcolormesh(xs, ys, grid, cmap="viridis", shading="nearest", rasterized=True)
    _contours(ax, xs, ys, grid, "px")
    if colorbar:
        fig.colorbar(im, ax=ax, fraction=0.04, pad=0.02, label="1-sigma (px)")
    return True


def uncertainty_figure(result: CalibrationResult) -> Figure:
    """The 1-sigma projection uncertainty over the image, colour with contours."""
    fig = page("Projection uncertainty over the image",
               "How far off, 1-sigma, the calibrated camera may place a point in each part of "
               "the image, from the pictures given alone (noise, not bias). Small and even is "
               "good; where it is large, add pictures with the board in that part of the "
               "image, tilted.")
    ax = image_axes(fig, result.image_size)
    if draw_uncertainty(fig, ax, result):
        ax.plot(result.points_px[:, 0], result.points_px[:, 1], ",", color="white",
                alpha=0.3, rasterized=True)
        ax.set_title(f"RMS {result.projection_uncertainty_rms_px:.3f} px, largest "
                     f"{result.projection_uncertainty_max_px:.3f} px (white dots: points used)",
                     fontsize=10)
    return fig


def lens_displacement(cam: CameraModel, pixels: np.ndarray) -> np.ndarray:
    """(N, 2) how far the lens moves each image pixel of ``pixels`` (N, 2) from where a
    pinhole camera of the same K would image its ray: image minus pinhole position, pixels;
    NaN where the ray cannot be found."""
    pix = np.asarray(pixels, np.float64).reshape(-1, 2)
    rays, ok = cam.unproject(pix)
    K = cam.K
    pinhole = rays[:, :2] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    shift = pix - pinhole
    shift[~ok] = np.nan
    return shift


def distortion_figure(result: CalibrationResult) -> Figure:
    """How far the lens moves each image point from where a pinhole camera (the same focal
    length and principal point) would see it: magnitude, contours and arrows."""
    fig = page("Lens distortion",
               "Colour: how many pixels the lens moves each image point from where an ideal "
               "pinhole camera would show it; arrows: the direction, from the pinhole image to "
               "the real one. Large values are normal for wide-angle lenses; they are what "
               "undistortion removes.")
    ax = image_axes(fig, result.image_size)
    w, h = result.image_size
    xs = np.linspace(0, w - 1, 81)
    ys = np.linspace(0, h - 1, max(2, round(81 * h / w)))
    gx, gy = np.meshgrid(xs, ys)
    pix = np.stack([gx.ravel(), gy.ravel()], axis=1)
    shift = lens_displacement(solution_camera(solution_of(result), result.image_size), pix)
    mag = np.linalg.norm(shift, axis=1).reshape(gx.shape)
    finite = mag[np.isfinite(mag)]
    # a fisheye's displacement from the pinhole image grows without bound towards 90 deg:
    # the colours span the inner 95 % of the image so the rest stays readable
    top = float(np.percentile(finite, 95)) if len(finite) else 1.0
    clipped = bool(len(finite)) and float(finite.max()) > 1.5 * top
    im = ax.pcolormesh(xs, ys, mag, cmap="magma", shading="nearest", rasterized=True,
                       vmin=0.0, vmax=top if clipped else None)
    _contours(ax, xs, ys, np.where(mag <= top, mag, np.nan) if clipped else mag, "px")
    fig.colorbar(im, ax=ax, fraction=0.04, pad=0.02, extend="max" if clipped else "neither",
                 label="displacement (px)")
    sel = (slice(None, None, 8), slice(None, None, 8))
    sx, sy = shift[:, 0].reshape(gx.shape)[sel], shift[:, 1].reshape(gx.shape)[sel]
    lengths = np.hypot(sx, sy)
    ref = float(np.nanmedian(lengths)) if np.isfinite(lengths).any() else 0.0
    # arrows to scale unless that makes the median one shorter than 3 % or longer than 8 %
    # of the image width
    gain = 1.0 if 0.03 * w <= ref <= 0.08 * w else _round_down(0.06 * w / max(ref, 1e-6))
    keep = lengths * gain <= 0.15 * w  # the few longer ones would cross the page
    ax.quiver(gx[sel][keep] - gain * sx[keep], gy[sel][keep] - gain * sy[keep],
              gain * sx[keep], gain * sy[keep], angles="xy", scale_units="xy", scale=1.0,
              color="#49c0ff", width=0.0025)
    worst = float(finite.max()) if len(finite) else float("nan")
    scale = (" (arrows to scale)" if gain == 1.0 else f" (arrows magnified {gain:g} times)"
             if gain > 1.0 else f" (arrows shrunk to {gain:g} of their length)")
    ax.set_title(f"largest displacement {worst:.1f} px" + scale, fontsize=10)
    return fig


def draw_coverage(ax: Axes, image_size: tuple[int, int], points_px: np.ndarray,
                  outliers_px: np.ndarray | None = None, *, dot: float = 1.5) -> int:
    """Points over the image (image axes) on the 8 x 6 coverage grid, each cell shaded by how
    many it holds, empty ones pink; returns the finite points drawn."""
    w, h = image_size
    gx, gy = COVERAGE_GRID
    given = np.asarray(points_px, np.float64).reshape(-1, 2)
    pts = given[np.all(np.isfinite(given), axis=1)]
    counts = coverage_cells_of(image_size, pts)
    top = max(float(counts.max()), 1.0)
    for j in range(gy):
        for i in range(gx):
            c = counts[j, i]
            colour = "#ffd2d2" if c == 0 else (1 - 0.35 * c / top, 1.0, 1 - 0.35 * c / top)
            ax.add_patch(Rectangle((i * w / gx - 0.5, j * h / gy - 0.5), w / gx, h / gy,
                                   facecolor=colour, edgecolor=GREY, lw=0.6, zorder=0))
    ax.plot(pts[:, 0], pts[:, 1], ".", ms=dot, color=BLUE, zorder=2, rasterized=True)
    if outliers_px is not None and len(outliers_px):
        ax.plot(outliers_px[:, 0], outliers_px[:, 1], "x", ms=4, color=RED, zorder=3,
                label=f"{len(outliers_px)} outliers left out")
        ax.legend(loc="upper right", fontsize=8)
    return len(pts)


def coverage_figure(image_size: tuple[int, int], points_px: np.ndarray, title: str,
                    outliers_px: np.ndarray | None = None) -> Figure:
    """Every point over the image and the 8 x 6 coverage grid shaded by how many points each
    cell holds; empty cells pink. ``points_px`` (P, 2), pixels."""
    fig = page(title,
               "Every board point (blue dots) over the image. The grid cells are shaded "
               "by how many points they hold; pink cells hold none, so the lens there is "
               "guessed from elsewhere. Move the board so that pink cells fill.")
    ax = image_axes(fig, image_size)
    n = draw_coverage(ax, image_size, points_px, outliers_px)
    covered = float(np.mean(coverage_cells_of(image_size, points_px) > 0))
    gx, gy = COVERAGE_GRID
    ax.set_title(f"{n} points; {100 * covered:.0f}% of the {gx} x {gy} grid covered",
                 fontsize=10)
    return fig


def coverage_cells_of(image_size: tuple[int, int], points_px: np.ndarray) -> np.ndarray:
    """(gy, gx) points in each cell of the coverage grid."""
    w, h = image_size
    gx, gy = COVERAGE_GRID
    given = np.asarray(points_px, np.float64).reshape(-1, 2)
    pts = given[np.all(np.isfinite(given), axis=1)]
    counts = np.zeros((gy, gx))
    np.add.at(counts, (np.clip((pts[:, 1] / h * gy).astype(int), 0, gy - 1),
                       np.clip((pts[:, 0] / w * gx).astype(int), 0, gx - 1)), 1)
    return counts


def per_view_figure(result: CalibrationResult) -> Figure:
    """The RMS error of each picture used (bars, by its position in the input) and the
    pictures left out, marked by why."""
    fig = page("Error per picture, and the pictures left out",
               "Bars: how well the camera fits each picture used (RMS, px). One bar far above "
               "the others is a picture that may be blurred or show a bent board. Marks under "
               "the axis: pictures left out, coloured by the reason (listed on the right).")
    ax = fig.add_axes((0.07, 0.16, 0.6, 0.72))
    used = np.asarray(result.views_used, int)
    err = np.asarray(result.per_view_rms_px, np.float64)
    ax.bar(used, err, width=0.8, color=BLUE, label=f"{len(used)} used")
    top = float(np.nanmax(err)) if len(err) else 1.0
    if len(err):
        med = float(np.median(err))
        ax.axhline(med, color=RED, lw=1, label=f"median {med:.3f} px")
    kinds = dropped_kinds(result.views_dropped)
    colours = ["#e08a00", "#7b3fa0", "#2a9d5c", "#b5651d", "#d04f9b", "#555555"]
    lines = []
    for k, (kind, views) in enumerate(kinds.items()):
        colour = colours[min(k, len(colours) - 1)]
        xs = [d.view_index for d in views]
        ax.plot(xs, np.full(len(xs), -0.04 * max(top, 1e-6)), "|", ms=9, color=colour,
                label=f"{len(views)} left out: {kind[:40]}")
        example = views[0]
        lines.append(textwrap.fill(f"{len(views)} x {kind}", 52) + "\n" + textwrap.fill(
            f"e.g. #{example.view_index} {example.source[-40:]}: {example.reason[:90]}", 52,
            initial_indent="   ", subsequent_indent="   "))
    ax.set_ylim(-0.08 * max(top, 1e-6), max(top, 1e-6) * 1.15)
    ax.set_xlabel("picture (position in the input)")
    ax.set_ylabel("RMS error (px)")
    ax.legend(fontsize=7, loc="upper left")
    text = "\n".join(lines[:8]) if lines else "no picture was left out"
    fig.text(0.70, 0.86, "Left out, and why:\n\n" + text, fontsize=7.5, va="top",
             family="monospace")
    return fig
