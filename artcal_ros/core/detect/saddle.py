"""Sub-pixel saddle points (X-corners) of chessboard and ChArUco boards, from an image model.

Near an inner corner the print is two straight edges crossing: a pattern
``sign(u1) * sign(u2)`` where ``u1``, ``u2`` are the signed distances to the two edge
lines through the corner ``c``. The lens blurs it with a point-spread function and each
pixel integrates it over its area; in linear light a pixel at ``p`` reads

    I(p) = (a + b * E(u1 / s) * E(u2 / s)) * (1 + g . (p - c)),    E(t) = erf(t / sqrt(2)),

with ``u_k = n_k . (p - c)`` for the unit normals ``n_k`` of the edges (angles ``alpha_k``),
``s`` the blur (Gaussian PSF and pixel box together), ``a``, ``b`` the mean level and
contrast of the print, ``g`` the light's relative gradient across the window (light
multiplies the print's reflectance: an additive gradient would tilt the dark and the white
quadrants alike and pull the centre towards the darker side). For perpendicular edges this is
the exact blurred pattern; for oblique ones (perspective) the product is an approximation
whose error is point-symmetric about ``c``, so it does not move the fitted centre.

All corners of an image are fitted at once (batched Levenberg-Marquardt over the nine
parameters) on integer pixels inside a window laid out in board coordinates: every pixel
whose board position (through a local affine map from neighbouring points) lies within
``window`` squares of the corner, and, where the board prints something else inside the
white squares (ChArUco markers), only the white band ``band`` squares wide along the edges.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_SQRT2 = float(np.sqrt(2.0))
_GAUSS = float(np.sqrt(2.0 / np.pi))
MAX_RADIUS_PX = 12      # half-size of the pixel box around a corner
GUARD_PX = 2.0          # distance kept from other printed edges, pixels (beyond the blur)
# A pixel integrates over its area: a perfect step already reads as a blur of 1 / sqrt(12)
# px. Sharpened photographs (JPEG cameras) can fit steeper; the floor keeps the model smooth.
MIN_BLUR_PX = 0.29
MIN_HALF_PX = 2.5       # smallest half-size of a window, pixels
MIN_PIXELS = 15         # fewest pixels a fit of the nine parameters is made from


def erf(x: np.ndarray) -> np.ndarray:
    """The error function, vectorised (Abramowitz & Stegun 7.1.26; |error| < 1.5e-7)."""
    z = np.abs(x)
    t = 1.0 / (1.0 + 0.3275911 * z)
    poly = t * (0.254829592 + t * (-0.284496736 + t * (1.421413741
                                                      + t * (-1.453152027 + t * 1.061405429))))
    return np.sign(x) * (1.0 - poly * np.exp(-z * z))


@dataclass(frozen=True)
class SaddleFit:
    """Fitted saddle points.

    Attributes:
        points_px: (K, 2) float64 refined positions, pixels (OpenCV convention).
        sigma_px: (K,) float64 1-sigma position error from the fit's covariance, pixels.
        ok: (K,) bool, the fit converged to a plausible X-corner of the expected polarity.
        blur_px: (K,) float64 fitted blur ``s``, pixels.
        contrast: (K,) float64 fitted ``|b|`` relative to the paper level ``a``.
    """

    points_px: np.ndarray
    sigma_px: np.ndarray
    ok: np.ndarray
    blur_px: np.ndarray
    contrast: np.ndarray


def _model(theta: np.ndarray, dx: np.ndarray, dy: np.ndarray, want_jac: bool
           ) -> tuple[np.ndarray, np.ndarray | None]:
    """Model values (K, P) and Jacobian (K, 9, P) for offsets dx, dy (K, P) from the box
    origin; theta (K, 9): cx, cy, alpha1, alpha2, s, a, b, gx, gy."""
    cx, cy, a1, a2, s, a, b, gx, gy = (theta[:, i:i + 1] for i in range(9))
    ex, ey = dx - cx, dy - cy
    n1x, n1y = -np.sin(a1), np.cos(a1)
    n2x, n2y = -np.sin(a2), np.cos(a2)
    u1 = n1x * ex + n1y * ey
    u2 = n2x * ex + n2y * ey
    E1, E2 = erf(u1 / (_SQRT2 * s)), erf(u2 / (_SQRT2 * s))
    S = E1 * E2
    light = 1.0 + gx * ex + gy * ey
    printed = a + b * S
    val = printed * light
    if not want_jac:
        return val, None
    g1 = _GAUSS / s * np.exp(-0.5 * (u1 / s) ** 2)
    g2 = _GAUSS / s * np.exp(-0.5 * (u2 / s) ** 2)
    dS_du1, dS_du2 = g1 * E2, E1 * g2
    J = np.empty((val.shape[0], 9, val.shape[1]))
    bg1, bg2 = b * light * dS_du1, b * light * dS_du2
    J[:, 0] = -(bg1 * n1x + bg2 * n2x) - printed * gx
    J[:, 1] = -(bg1 * n1y + bg2 * n2y) - printed * gy
    # du_k / dalpha_k = -(t_k . e), t_k = (cos, sin) the edge direction
    J[:, 2] = -bg1 * (np.cos(a1) * ex + np.sin(a1) * ey)
    J[:, 3] = -bg2 * (np.cos(a2) * ex + np.sin(a2) * ey)
    J[:, 4] = -(bg1 * u1 + bg2 * u2) / s
    J[:, 5] = light
    J[:, 6] = S * light
    J[:, 7] = printed * ex
    J[:, 8] = printed * ey
    return val, J


def _window(A: np.ndarray, centre: np.ndarray, dx: np.ndarray, dy: np.ndarray,
            window: float, band: float | None, black_diagonal: np.ndarray) -> np.ndarray:
    """(K, P) float mask of the pixels to fit (see the module docstring)."""
    Ainv = np.linalg.inv(A)                                          # pixels -> squares
    ex, ey = dx - centre[:, :1], dy - centre[:, 1:]
    u = Ainv[:, 0, 0:1] * ex + Ainv[:, 0, 1:2] * ey
    v = Ainv[:, 1, 0:1] * ex + Ainv[:, 1, 1:2] * ey
    # a pixel's size in squares along each board axis, for the guard distances
    scale = np.sqrt(np.abs(np.linalg.det(A)))[:, None]              # pixels per square
    guard = np.minimum(GUARD_PX / scale, 0.2)      # small squares: a fifth of one at most
    # at least MIN_HALF_PX pixels each way (tiny squares), never past 0.8 squares
    half = np.minimum(np.maximum(window - guard, MIN_HALF_PX / scale), 0.8)
    inside = np.maximum(np.abs(u), np.abs(v)) <= half
    if band is not None:
        # quadrants up-left / down-right are black where black_diagonal
        same_sign = (u * v) > 0
        black = np.where(black_diagonal[:, None], same_sign, ~same_sign)
        inside &= black | (np.minimum(np.abs(u), np.abs(v)) <= band - guard)
    return inside.astype(np.float64)


def fit_saddles(lin: np.ndarray, guess_px: np.ndarray, axes_px: np.ndarray,
                black_diagonal: np.ndarray, *, window: float = 0.6,
                band: float | None = None, iterations: int = 10) -> SaddleFit:
    """Refine saddle points by fitting the blurred X-corner model to linear-light pixels.

    Args:
        lin: (H, W) float32/float64 image in linear light.
        guess_px: (K, 2) starting positions, pixels.
        axes_px: (K, 2, 2) local affine map from board offsets (in squares) to pixels:
            column 0 is the image of one square along the board's x axis, column 1 along y.
        black_diagonal: (K,) bool, the squares up-left and down-right (board frame) of each
            corner are black.
        window: half-size of the fitted window, squares (< 1: the next edges start there).
        band: width of the white band along the edges inside white squares (ChArUco: the
            marker's quiet zone in squares); None where white squares are plain.
        iterations: Levenberg-Marquardt steps.

    Returns:
        :class:`SaddleFit`.
    """
    K = len(guess_px)
    h, w = lin.shape
    empty = SaddleFit(np.zeros((0, 2)), np.zeros(0), np.zeros(0, bool), np.zeros(0), np.zeros(0))
    if K == 0:
        return empty
    guess = np.asarray(guess_px, dtype=np.float64).reshape(K, 2)
    A = np.asarray(axes_px, dtype=np.float64).reshape(K, 2, 2)
    scale = np.sqrt(np.abs(np.linalg.det(A)))
    r = int(np.clip(np.ceil(np.max(window * np.abs(A).sum(axis=2))), 2, MAX_RADIUS_PX))
    offs = np.arange(-r, r + 1, dtype=np.float64)
    oy, ox = (g.ravel() for g in np.meshgrid(offs, offs, indexing="ij"))
    base = np.round(guess)
    px = base[:, :1] + ox[None, :]
    py = base[:, 1:] + oy[None, :]
    valid = (px >= 0) & (px <= w - 1) & (py >= 0) & (py <= h - 1)
    img = lin[np.clip(py, 0, h - 1).astype(np.intp), np.clip(px, 0, w - 1).astype(np.intp)]
    img = img.astype(np.float64)
    dx, dy = px - base[:, :1], py - base[:, 1:]     # offsets from the box origin
    black_diagonal = np.asarray(black_diagonal, dtype=bool).reshape(K)

    # start: edges along the board axes, blur 1 px, a and b from the pixels
    theta = np.zeros((K, 9))
    theta[:, :2] = guess - base
    theta[:, 2] = np.arctan2(A[:, 1, 0], A[:, 0, 0])
    theta[:, 3] = np.arctan2(A[:, 1, 1], A[:, 0, 1])
    theta[:, 4] = 1.0
    for _pass in range(2):
        window_mask = _window(A, theta[:, :2], dx, dy, window, band, black_diagonal)
        wgt = window_mask * valid
        theta = _lm(theta, img, dx, dy, wgt, iterations if _pass == 0 else iterations // 2,
                    linear_start=_pass == 0)
    val, J = _model(theta, dx, dy, True)
    assert J is not None
    res = (img - val) * wgt
    n = wgt.sum(axis=1)
    # a window cut by the image edge sees part of an X only: not measured (the pixel box
    # may cut it, symmetrically about the start, where squares are large)
    whole = (window_mask * ~valid).sum(axis=1) == 0
    dof = np.maximum(n - 9, 1)
    rms = np.sqrt((res ** 2).sum(axis=1) / dof)
    JtJ = _normal(wgt, J) + 1e-12 * np.eye(9)
    with np.errstate(all="ignore"):
        cov = np.linalg.pinv(JtJ)
    sigma = np.sqrt(np.abs(cov[:, 0, 0] + cov[:, 1, 1]) / 2) * rms
    points = theta[:, :2] + base
    s, a, b = np.abs(theta[:, 4]), theta[:, 5], theta[:, 6]
    contrast = np.abs(b) / np.maximum(np.abs(a), 1e-12)
    # polarity: the model's value a quarter square into the down-right quadrant
    probe = A @ np.array([0.3, 0.3])
    pv, _ = _model(theta, (theta[:, 0] + probe[:, 0])[:, None],
                   (theta[:, 1] + probe[:, 1])[:, None], False)
    dark_down_right = pv[:, 0] < a
    moved = np.linalg.norm(points - guess, axis=1)
    angle = np.abs(np.sin(theta[:, 2] - theta[:, 3]))
    ok = (np.all(np.isfinite(theta), axis=1) & (moved < 0.3 * scale) & (s < 0.25 * scale)
          & (contrast > 0.05) & (rms < 0.3 * np.abs(b))
          & (dark_down_right == black_diagonal) & (angle > 0.2) & (n >= MIN_PIXELS)
          & (sigma < 0.1 * scale) & whole)
    return SaddleFit(points, sigma, ok, s, contrast)


def _normal(wgt: np.ndarray, J: np.ndarray) -> np.ndarray:
    """(K, n, n) weighted normal matrices J^T W J of (K, n, P) Jacobians."""
    return np.matmul(J * wgt[:, None, :], J.transpose(0, 2, 1))


def _gradient(wgt: np.ndarray, J: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(K, n) weighted J^T W r."""
    return np.matmul(J * wgt[:, None, :], r[..., None])[..., 0]


def _lm(theta: np.ndarray, img: np.ndarray, dx: np.ndarray, dy: np.ndarray, wgt: np.ndarray,
        iterations: int, *, linear_start: bool) -> np.ndarray:
    """Batched Levenberg-Marquardt of the saddle model (K corners at once)."""
    K = len(theta)
    theta = theta.copy()
    if linear_start:
        # a and b by linear least squares for the starting geometry
        val, J = _model(theta, dx, dy, True)
        assert J is not None
        L = J[:, 5:7]            # the light is flat at the start: I = a + b S
        M = _normal(wgt, L) + 1e-9 * np.eye(2)
        rhs = _gradient(wgt, L, img)
        theta[:, 5:7] = np.linalg.solve(M, rhs[..., None])[..., 0]
    lam: np.ndarray = np.full(K, 1e-3)
    val, J = _model(theta, dx, dy, True)
    cost = (wgt * (img - val) ** 2).sum(axis=1)
    eye = np.eye(9)
    for _ in range(iterations):
        assert J is not None
        r = img - val
        JtJ = _normal(wgt, J)
        Jtr = _gradient(wgt, J, r)
        diag = np.einsum("kaa->ka", JtJ)
        Hm = JtJ + lam[:, None, None] * (diag[:, :, None] * eye + 1e-9 * eye)
        try:
            step = np.linalg.solve(Hm, Jtr[..., None])[..., 0]
        except np.linalg.LinAlgError:
            break
        trial = theta + step
        trial[:, 4] = np.maximum(np.abs(trial[:, 4]), MIN_BLUR_PX)
        tval, tJ = _model(trial, dx, dy, True)
        tcost = (wgt * (img - tval) ** 2).sum(axis=1)
        better = np.isfinite(tcost) & (tcost < cost)
        theta[better] = trial[better]
        val = np.where(better[:, None], tval, val)
        assert tJ is not None
        J[better] = tJ[better]
        cost = np.where(better, tcost, cost)
        lam = np.asarray(np.where(better, lam * 0.3, lam * 10.0))
    return theta
