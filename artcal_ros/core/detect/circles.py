"""Circle grid centres with identities: OpenCV finds the grid, our edge fit measures the centres.

A circle grid has no code, so a view names its circles only when OpenCV's
``findCirclesGrid`` finds the whole ``cols`` x ``rows`` grid; partial views give no points.

Identities: the grid's order is checked against the board: the order (among the grid's
flips and turns) must fit a homography from the board's object points to the image with
the print facing the camera. Both grids look the same turned by a half turn (a square
symmetric grid also by a quarter turn); of the orders that fit, the one whose point 0 is
nearest the image's top-left corner (least x + y, as for the chessboard and in
camera_calibration) is taken. Ids are exact up to that symmetry, which no image of the
print can resolve and a calibration does not need. A blob off the place its grid
neighbours predict is left out, and a view is refused when circles show where the
pattern's next row or column would be (a larger print: OpenCV finds a smaller grid in it,
and ids counted from its edge would be wrong).

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
from artcal_ros.core.detect.lens import DivisionLens, Lens

_RAYS = 64
_STEP_PX = 0.25
_INNER = (0.15, 0.5)    # the dark inside, fractions of the circle's radius along a ray
_OUTER = (1.5, 1.9)     # the paper around it (neighbours start beyond 2 radii)


def _blob_detector() -> cv2.SimpleBlobDetector:
    p = cv2.SimpleBlobDetector.Params()
    # OpenCV's defaults (25 - 5000 px) miss small far circles and large near ones
    p.minArea = 8.0
    p.maxArea = 1e6
    p.minDistBetweenBlobs = 3.0
    return cv2.SimpleBlobDetector.create(p)


def find_circle_grid(gray8: np.ndarray, board: Board) -> np.ndarray | None:
    """(rows, cols, 2) float64 OpenCV's grid of blob centres in its own order, or None."""
    flags = (cv2.CALIB_CB_ASYMMETRIC_GRID if board.board_type == "acircles"
             else cv2.CALIB_CB_SYMMETRIC_GRID)
    size = (board.cols, board.rows)
    detector = _blob_detector()
    # the default grid search fails on steep views that clustering finds, and the reverse
    for extra in (0, cv2.CALIB_CB_CLUSTERING):
        found, centres = cv2.findCirclesGrid(gray8, size, flags=flags | extra,
                                             blobDetector=detector)
        if found and centres is not None and len(centres) == board.cols * board.rows:
            return np.asarray(centres, dtype=np.float64).reshape(board.rows, board.cols, 2)
    return None


def _orders(grid: np.ndarray) -> list[np.ndarray]:
    """The grid's re-orderings that keep its shape: flips, half turn, and on a square grid
    the transposes and quarter turns."""
    out = [grid, grid[::-1, ::-1], grid[::-1], grid[:, ::-1]]
    if grid.shape[0] == grid.shape[1]:
        t = grid.transpose(1, 0, 2)
        out += [t, t[::-1, ::-1], t[::-1], t[:, ::-1]]
    return out


def _homography(board_xy: np.ndarray, image_xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares homography board (M, 2) metres -> image (M, 2) px and its RMS residual."""
    H, _ = cv2.findHomography(board_xy, image_xy, 0)
    if H is None:
        return np.eye(3), float("inf")
    p = cv2.perspectiveTransform(board_xy.reshape(-1, 1, 2), H).reshape(-1, 2)
    return H, float(np.sqrt(np.mean(np.sum((p - image_xy) ** 2, axis=1))))


def orient_grid(grid: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray] | None:
    """The grid re-ordered to the board's ids (see the module docstring) and its homography
    (board metres -> image px); None when no order fits the board."""
    obj = board.object_points()[:, :2]
    spacing_px = np.median(np.linalg.norm(np.diff(grid.reshape(-1, 2), axis=0), axis=1))
    fits = []
    for g in _orders(grid):
        H, rms = _homography(obj, g.reshape(-1, 2))
        # the print faces the camera: the board's x and y axes keep their handedness
        J = H[:2, :2] - np.outer(H[:2, 2], H[2, :2])
        if np.linalg.det(J) > 0:
            fits.append((rms, g, H))
    if not fits:
        return None
    best = min(f[0] for f in fits)
    # a homography fits the true order to the lens's bending (a few px at a webcam's corner);
    # a wrong order is off by whole spacings
    if best > 0.25 * spacing_px:
        return None
    good = [f for f in fits if f[0] <= best + 0.1 * spacing_px]
    _, g, H = min(good, key=lambda f: float(f[1][0, 0].sum()))
    return g, H


def misplaced(points_px: np.ndarray, cells: np.ndarray, tolerance: float = 0.3) -> np.ndarray:
    """(n,) bool: grid points off the place their neighbours predict (a blob OpenCV put in
    the grid that is not that circle).

    Each point is predicted by an affine map of the lattice cells (n, 2) fitted to the
    points within two cells of it (itself left out); over so small a patch perspective
    and lens are nearly affine. The worst point beyond ``tolerance`` local spacings is
    flagged and left out of its neighbours' fits, and so on until none is.
    """
    n = len(points_px)
    out = np.zeros(n, bool)
    X = np.column_stack([cells[:, 1], cells[:, 0], np.ones(n)]).astype(np.float64)
    near_all = np.abs(cells[:, None, :] - cells[None, :, :]).max(axis=2) <= 2
    np.fill_diagonal(near_all, False)
    for _ in range(n):
        worst, worst_k = 1.0, -1
        for k in np.flatnonzero(~out):
            near = near_all[k] & ~out
            if near.sum() < 4:
                continue
            coef = np.linalg.lstsq(X[near], points_px[near], rcond=None)[0]
            pitch = np.sqrt(abs(np.linalg.det(coef[:2])))
            miss = np.linalg.norm(X[k] @ coef - points_px[k]) / (tolerance * pitch + 1e-12)
            if miss > worst:
                worst, worst_k = miss, k
        if worst_k < 0:
            break
        out[worst_k] = True
    return out


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
        H, _ = _homography(obj[ok], centres[ok])
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
        return _homography(obj, u)[1]

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


def border_cells(board: Board) -> tuple[np.ndarray, np.ndarray]:
    """Lattice cells one lattice step outside the grid where the pattern would have its
    next circles (on the printed margin).

    Returns:
        (cells (K, 2) int64 (row, column); side (K,) int64: 0 above, 1 below, 2 left,
        3 right of the grid).
    """
    circles = board.circles
    assert circles is not None
    cells = board.point_cells(board.point_ids)
    c0, c1 = int(cells[:, 1].min()), int(cells[:, 1].max())
    rows = np.arange(-1, board.rows + 1)
    cols = np.arange(c0 - 1, c1 + 2)
    r, c = (a.ravel() for a in np.meshgrid(rows, cols, indexing="ij"))
    beyond = (r < 0) | (r >= board.rows) | (c < c0) | (c > c1)
    corner = ((r < 0) | (r >= board.rows)) & ((c < c0) | (c > c1))
    fits = (c - r) % 2 == 0 if circles.asymmetric else np.ones_like(beyond)
    keep = beyond & ~corner & fits
    side = np.select([r < 0, r >= board.rows, c < c0], [0, 1, 2], 3)
    return np.stack([r[keep], c[keep]], axis=1).astype(np.int64), side[keep]


def grid_continues(lin: np.ndarray, board: Board, H_u: np.ndarray, lens: Lens,
                   centres_px: np.ndarray, radius_px: float) -> bool:
    """Whether the image shows circles where the pattern's next row or column would be:
    then the print is larger than the board configured (or another grid), and ids counted
    from this grid's edge would be wrong.

    Args:
        H_u: (3, 3) board metres -> straightened pixels. centres_px: (M, 2) the circles found.
        radius_px: the circles' typical radius in the image.
    """
    s = board.square_length
    obj = board.object_points()[:, :2]
    # paper between the circles: half a step diagonally (symmetric), one step across
    # (asymmetric: the empty lattice cells)
    gap = obj + (np.array([s, 0.0]) if board.board_type == "acircles" else 0.5 * s)
    x1, y1 = board.extent_m[2:]
    gap = gap[(gap[:, 0] < x1) & (gap[:, 1] < y1)]

    def image_of(board_xy: np.ndarray) -> np.ndarray:
        mapped = cv2.perspectiveTransform(board_xy.reshape(-1, 1, 2).astype(np.float64), H_u)
        return lens.distort(mapped.reshape(-1, 2))

    h, w = lin.shape
    r = max(1.0, 0.4 * radius_px)

    def level(points: np.ndarray) -> np.ndarray:
        out = np.full(len(points), np.nan)
        for k, (x, y) in enumerate(points):
            if r <= x < w - 1 - r and r <= y < h - 1 - r:
                patch = lin[int(y - r):int(y + r) + 1, int(x - r):int(x + r) + 1]
                out[k] = float(np.median(patch))
        return out

    cells, side = border_cells(board)
    seen = level(image_of(cells[:, ::-1] * s))
    dark = float(np.nanmedian(level(centres_px)))
    paper = float(np.nanmedian(level(image_of(gap))))
    # circle-dark: nearer the circles' level than the paper's. A larger print shows a
    # whole row or column of them; one dark spot (the board's edge, clutter past it, an
    # extrapolation a few pixels off near the image's corner) is not that.
    is_dark = seen < dark + 0.35 * (paper - dark)
    for k in range(4):
        visible = np.isfinite(seen[side == k])
        hits = int(is_dark[side == k].sum())
        if hits >= 2 and hits >= 0.5 * visible.sum():
            return True
    return False


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
    H_u, _ = _homography(obj[ok], lens.undistort(first[ok]))
    centres = _centres(_conics(straight, ok), ok, obj, H_u)
    radius_px = float(np.median([np.median(np.linalg.norm(e - e.mean(axis=0), axis=1))
                                 for e, good in zip(edges, ok, strict=True) if good]))
    H_u, _ = _homography(obj[ok], centres[ok])
    if grid_continues(lin32, board, H_u, lens, lens.distort(centres[ok]), radius_px):
        return none
    ids = board.point_ids
    return ids[ok], lens.distort(centres[ok]), sigma[ok]
