"""Circle grid centres with identities: OpenCV finds the grid, our edge fit measures the centres.

A circle grid has no code, so a view names its circles only when OpenCV's
``findCirclesGrid`` finds the whole ``cols`` x ``rows`` grid; partial views give no points.

Identities (:mod:`artcal_ros.core.detect.circle_grid`): the grid's order is checked
against the board: the order (among the grid's flips and turns) must fit a homography from
the board's object points to the image with the print facing the camera. A symmetric grid
looks the same turned by a half turn (a square one by a quarter turn too), and so does an
asymmetric grid with an even number of rows; of the orders that fit, the one whose point 0
is nearest the image's top-left corner (least x + y, as for the chessboard and in
camera_calibration) is taken. Ids are exact up to that symmetry, which no image of the
print can resolve and a calibration does not need (an asymmetric grid with an odd number
of rows, OpenCV's 4 x 11, fits one order only: every id exact). A blob
off the place its grid neighbours predict is left out, and a view is refused when circles
show where the pattern's next row or column would be (a larger print: OpenCV finds a
smaller grid in it, and ids counted from its edge would be wrong).

Centres: OpenCV's blob centres are the centroids of thresholded blobs, and even an exact
ellipse's centre is not the image of the circle's centre under perspective. Each circle
is measured again in linear light: its edge is found along rays from the centre (where the
intensity crosses halfway between the inside's and the paper's level), and a conic is
fitted to those edge points. The image of the circle's centre is the pole, with respect
to that conic, of the image of the board plane's line at infinity (from the grid's
homography): projective maps keep poles and polars, and the centre of a circle is the pole
of the line at infinity. The lens would bend outlines and grid away from a conic and a
homography, so the edge points are first straightened through a known lens, or through a
one-term division lens fitted to the view (the one under which the circles' centres best
fit a homography); conics, homography and poles are computed there and the centres mapped
back to the image.
"""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.circle_grid import (
    find_circle_grid,
    grid_continues,
    homography,
    misplaced,
    orient_grid,
)
from artcal_ros.core.detect.lens import DivisionLens, Lens

_RAYS = 64
_STEP_PX = 0.25
_INNER = (0.15, 0.5)    # the dark inside, fractions of the circle's radius along a ray
_OUTER = (1.5, 1.9)     # the paper around it (neighbours start beyond 2 radii)


def _edge_points(lin: np.ndarray, centre: np.ndarray, radii: np.ndarray,
                 angles: np.ndarray) -> np.ndarray:
    """(K, 2) sub-pixel edge points of one dark circle: where each ray's linear intensity
    crosses halfway between the inside's and the paper's level (NaN rows where it does not).

    Args:
        centre: (2,) start of the rays, px. radii: (R,) the circle's radius along each ray, px.
        angles: (R,) ray directions, radians.
    """
    t = np.arange(0.0, _OUTER[1] * radii.max() + _STEP_PX, _STEP_PX)
    d = np.stack([np.cos(angles), np.sin(angles)], axis=1)
    xy = centre + t[None, :, None] * d[:, None, :]                  # (R, T, 2)
    prof = cv2.remap(lin, xy[..., 0].astype(np.float32), xy[..., 1].astype(np.float32),
                     cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1.0)
    rel = t[None, :] / radii[:, None]
    inner = (rel >= _INNER[0]) & (rel <= _INNER[1])
    outer = (rel >= _OUTER[0]) & (rel <= _OUTER[1])
    n_in, n_out = inner.sum(axis=1), outer.sum(axis=1)
    lo = np.where(inner, prof, 0.0).sum(axis=1) / np.maximum(n_in, 1)
    hi = np.where(outer, prof, 0.0).sum(axis=1) / np.maximum(n_out, 1)
    # rays leaving the image (read as -1), or without contrast, give no edge point
    off = np.where(inner | outer, prof, 1.0).min(axis=1) < 0
    good = (n_in > 0) & (n_out > 0) & ~off & (hi - lo > 0.05 * hi)
    mid = 0.5 * (lo + hi)[:, None]
    seg = (rel > _INNER[1]) & (rel < _OUTER[0])
    up = (prof[:, :-1] < mid) & (prof[:, 1:] >= mid) & seg[:, :-1] & seg[:, 1:]
    good &= up.sum(axis=1) == 1      # no crossing, or a bumpy profile: no edge point
    i = np.argmax(up, axis=1)
    rows = np.arange(len(angles))
    p0, p1 = prof[rows, i], prof[rows, i + 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = t[i] + (mid[:, 0] - p0) / (p1 - p0) * _STEP_PX
    out = centre + s[:, None] * d
    out[~good] = np.nan
    return out


def fit_conic(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares conic through points and each point's distance from it.

    Args:
        pts: (K, 2) px, K >= 5.

    Returns:
        (C (3, 3) symmetric, x^T C x = 0 for x = (u, v, 1); residuals (K,) px, first-order
        geometric distances).
    """
    m = pts.mean(axis=0)
    s = np.sqrt(2.0) / max(float(np.mean(np.linalg.norm(pts - m, axis=1))), 1e-12)
    T = np.array([[s, 0.0, -s * m[0]], [0.0, s, -s * m[1]], [0.0, 0.0, 1.0]])
    x, y = (pts[:, 0] - m[0]) * s, (pts[:, 1] - m[1]) * s
    A = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], axis=1)
    a, b, c, d, e, f = np.linalg.svd(A, full_matrices=False)[2][-1]
    Cn = np.array([[a, b / 2, d / 2], [b / 2, c, e / 2], [d / 2, e / 2, f]])
    gx, gy = 2 * a * x + b * y + d, b * x + 2 * c * y + e
    res = (A @ np.array([a, b, c, d, e, f])) / np.maximum(np.hypot(gx, gy), 1e-12) / s
    return T.T @ Cn @ T, res


def measure_circle(lin: np.ndarray, centre: np.ndarray, H: np.ndarray, board_centre: np.ndarray,
                   radius_m: float) -> tuple[np.ndarray, float, np.ndarray]:
    """One circle's conic, measured from its edge.

    Args:
        centre: (2,) px, where to start the rays (near the circle's centre).
        H: (3, 3) board metres -> image px homography of the view.
        board_centre: (2,) the circle's centre on the board, metres.

    Returns:
        (C (3, 3) or NaN; RMS edge residual px; edge points (K, 2) px used).
    """
    # the circle's outline as the homography predicts it: its radius along each ray
    phi = np.linspace(0.0, 2 * np.pi, 32, endpoint=False)
    ring = board_centre + radius_m * np.stack([np.cos(phi), np.sin(phi)], axis=1)
    # its shape about the predicted centre (the lens may move the whole circle by pixels)
    mapped = cv2.perspectiveTransform(np.vstack([ring, board_centre]).reshape(-1, 1, 2), H)
    outline = mapped[:-1, 0] - mapped[-1, 0]
    angles = np.linspace(0.0, 2 * np.pi, _RAYS, endpoint=False)
    ang_o = np.arctan2(outline[:, 1], outline[:, 0])
    rad_o = np.linalg.norm(outline, axis=1)
    order = np.argsort(ang_o)
    radii = np.interp(angles, ang_o[order], rad_o[order], period=2 * np.pi)
    nan = np.full((3, 3), np.nan)
    if radii.min() < 1.5:
        return nan, float("inf"), np.zeros((0, 2))
    pts = _edge_points(lin, centre, radii, angles)
    pts = pts[np.isfinite(pts[:, 0])]
    if len(pts) < 0.6 * _RAYS:
        return nan, float("inf"), pts
    C, res = fit_conic(pts)
    # one pass without the outliers (a speck of dirt, a ray that grazed a neighbour)
    mad = float(np.median(np.abs(res))) + 1e-3
    keep = np.abs(res) <= 4.0 * 1.4826 * mad
    if keep.sum() < 0.6 * _RAYS:
        return nan, float("inf"), pts
    pts = pts[keep]
    C, res = fit_conic(pts)
    return C, float(np.sqrt(np.mean(res ** 2))), pts


def pole_of_line(C: np.ndarray, line: np.ndarray) -> np.ndarray:
    """(2,) px: the pole of ``line`` (3,) with respect to the conic ``C`` (3, 3)."""
    p = np.linalg.solve(C, line)
    return p[:2] / p[2]


def _conics(edges: list[np.ndarray], ok: np.ndarray) -> np.ndarray:
    """(n, 3, 3) conics fitted to each circle's edge points (NaN where not ``ok``)."""
    out = np.full((len(edges), 3, 3), np.nan)
    for k in np.flatnonzero(ok):
        out[k] = fit_conic(edges[k])[0]
    return out


def _centres(conics: np.ndarray, ok: np.ndarray, obj: np.ndarray, H: np.ndarray,
             rounds: int = 2) -> np.ndarray:
    """(n, 2) px: each circle's centre as the pole of the vanishing line, the homography
    refitted to the centres between rounds."""
    centres = np.full((len(conics), 2), np.nan)
    for _ in range(rounds):
        line = np.linalg.solve(H.T, np.array([0.0, 0.0, 1.0]))
        for k in np.flatnonzero(ok):
            centres[k] = pole_of_line(conics[k], line)
        H, _ = homography(obj[ok], centres[ok])
    return centres


def fit_division_lens(centres_px: np.ndarray, obj: np.ndarray,
                      image_size: tuple[int, int]) -> DivisionLens:
    """The one-term division lens (centre at the image's centre) under which the circles'
    centres (M, 2) px best fit a homography of the board points (M, 2) metres."""
    w, h = image_size
    centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
    scale = 0.5 * float(np.hypot(w, h))

    def cost(lam: float) -> float:
        u = DivisionLens(lam, centre, scale).undistort(centres_px)
        return homography(obj, u)[1]

    lo, hi = -0.6, 0.6
    g = (np.sqrt(5.0) - 1) / 2
    a, b = hi - g * (hi - lo), lo + g * (hi - lo)
    fa, fb = cost(a), cost(b)
    for _ in range(40):     # golden section: the cost is smooth and single-welled here
        if fa < fb:
            hi, b, fb = b, a, fa
            a = hi - g * (hi - lo)
            fa = cost(a)
        else:
            lo, a, fa = a, b, fb
            b = lo + g * (hi - lo)
            fb = cost(b)
    return DivisionLens(0.5 * (lo + hi), centre, scale)


def detect_circles(gray8: np.ndarray, lin: np.ndarray, board: Board,
                   lens: Lens | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The circle grid's centres in one image.

    Args:
        gray8: (H, W) uint8 contrast-stretched grey (for OpenCV's grid finder).
        lin: (H, W) float32 linear-light grey (for the edge fit).
        board: a ``circles`` or ``acircles`` board.
        lens: a known lens; None: a one-term division lens fitted to this view's grid.

    Returns:
        (point_ids (M,) int64, points_px (M, 2) float64, point_sigma_px (M,) float64); empty
        unless the whole grid was found. Circles whose edge fit failed are left out.
    """
    none = (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(0))
    circles = board.circles
    assert circles is not None
    grid = find_circle_grid(gray8, board)
    if grid is None:
        return none
    oriented = orient_grid(grid, board)
    if oriented is None:
        return none
    grid, H = oriented
    start = grid.reshape(-1, 2)
    obj = board.object_points()[:, :2]
    lin32 = np.ascontiguousarray(lin, dtype=np.float32)
    n = len(obj)
    edges: list[np.ndarray] = []
    sigma = np.full(n, np.nan)
    bad = misplaced(start, board.point_cells(board.point_ids))
    if bad.mean() > 0.2:     # not a grid of this board's circles: no ids at all
        return none
    for k in range(n):
        if bad[k]:
            edges.append(np.zeros((0, 2)))
            continue
        _, rms, pts = measure_circle(lin32, start[k], H, obj[k], circles.radius)
        edges.append(pts)
        if np.isfinite(rms):
            # a conic's centre from K edge points of spread rms: about rms * sqrt(2 / K)
            sigma[k] = rms * np.sqrt(2.0 / len(pts))
    ok = np.isfinite(sigma)
    if ok.sum() < 8:
        return none
    first = _centres(_conics(edges, ok), ok, obj, H, rounds=1)
    if lens is None:
        lens = fit_division_lens(first[ok], obj[ok], (lin.shape[1], lin.shape[0]))
    # in straightened pixels the board's image is a homography and each outline a conic
    straight = [lens.undistort(e) if len(e) else e for e in edges]
    H_u, _ = homography(obj[ok], lens.undistort(first[ok]))
    centres = _centres(_conics(straight, ok), ok, obj, H_u)
    radius_px = float(np.median([np.median(np.linalg.norm(e - e.mean(axis=0), axis=1))
                                 for e, good in zip(edges, ok, strict=True) if good]))
    H_u, _ = homography(obj[ok], centres[ok])
    if grid_continues(lin32, board, H_u, lens, lens.distort(centres[ok]), radius_px):
        return none
    ids = board.point_ids
    return ids[ok], lens.distort(centres[ok]), sigma[ok]
