"""What the board prints, as the detection stages need it.

The markers' patterns as cell means under a few levels of blur (what a decoded
or re-read marker is compared with), the code cells behind each border side
that share the border's colour (the edge model's far edges), and the sides
beyond which the board puts another marker's tile (a known edge past the quiet
zone). Facts about the board only: nothing here reads an image.
"""

from __future__ import annotations

import numpy as np

from artcal_ros.core.board import Board

BLUR_LEVELS = (0.0, 0.08, 0.16, 0.22)


def blurred_patterns(pats: np.ndarray) -> np.ndarray:
    """(P, L, n * n) float: printed patterns (P, n, n) (True = white) as cell means under blur.

    Each level mixes a cell with its 4 neighbours (weight b) and diagonal ones (b^2),
    for b in :data:`BLUR_LEVELS`; outside the marker is the quiet zone, the
    opposite of the border's colour.

    Args:
        pats: (P, n, n) bool modules of P markers, border included, row-major.
    """
    P, n, _ = pats.shape
    f = pats.astype(np.float64)
    surround = 1.0 - f[:, 0, 0]
    pad = np.empty((P, n + 2, n + 2))
    pad[:] = surround[:, None, None]
    pad[:, 1:-1, 1:-1] = f
    out = np.empty((P, len(BLUR_LEVELS), n * n))
    for k, b in enumerate(BLUR_LEVELS):
        center = 1.0 - 4.0 * b - 4.0 * b * b
        acc = center * pad[:, 1:-1, 1:-1]
        for dy, dx, w in ((-1, 0, b), (1, 0, b), (0, -1, b), (0, 1, b), (-1, -1, b * b),
                          (-1, 1, b * b), (1, -1, b * b), (1, 1, b * b)):
            acc = acc + w * pad[:, 1 + dy:n + 1 + dy, 1 + dx:n + 1 + dx]
        out[:, k] = acc.reshape(P, n * n)
    return out


# over-exposure gains of :func:`clipped_patterns`: the paper white at 2, 4 and 8 times
# the level where the sensor saturates
CLIP_GAINS = (2.0, 4.0, 8.0)


def clipped_patterns(blurred: np.ndarray, gains: tuple[float, ...] = CLIP_GAINS
                     ) -> np.ndarray:
    """(P, L * (1 + G), n * n): blurred cell means (:func:`blurred_patterns`) as the sensor
    sees them over-exposed: ``min(1, g * mean)`` for each gain g, after the unclipped ones.

    Clipping spreads the white into every black cell by the same margin, so a lone black
    cell fades out before the solid border does; a marker in a clipped frame matches these
    much better than any unclipped level.

    Args:
        blurred: (P, L, n * n) float, 1 = white.
        gains: the over-exposures, > 1.
    """
    P, L, nn = blurred.shape
    out = [blurred] + [np.minimum(1.0, g * blurred) for g in gains]
    return np.concatenate(out, axis=1).reshape(P, L * (1 + len(gains)), nn)


def inner_border_cells(board: Board, ids: np.ndarray, rows: int = 2) -> np.ndarray:
    """(M, 4, rows, bits) bool: per side, the code cells behind the border that share its colour.

    Row 0 touches the border, row 1 is the next one inward. Sides run TL->TR,
    TR->BR, BR->BL, BL->TL; cells are listed in that direction.

    Args:
        board: the calibration board.
        ids: (M,) marker ids on the board.
        rows: code rows behind the border to list.
    """
    b = board.bits
    out = np.zeros((len(ids), 4, rows, b), dtype=bool)
    for k, marker_id in enumerate(ids):
        mod = board.marker_modules(int(marker_id))
        same = mod == mod[0, 0]
        for r in range(rows):
            out[k, 0, r] = same[1 + r, 1:b + 1]
            out[k, 1, r] = same[1:b + 1, b - r]
            out[k, 2, r] = same[b - r, 1:b + 1][::-1]
            out[k, 3, r] = same[1:b + 1, 1 + r][::-1]
    return out


def outer_neighbours(board: Board, ids: np.ndarray) -> np.ndarray:
    """(M, 4) bool: per side (top, right, bottom, left), another marker's tile lies beyond it.

    Args:
        board: the calibration board.
        ids: (M,) marker ids on the board.
    """
    out = np.zeros((len(ids), 4), dtype=bool)
    for k, marker_id in enumerate(ids):
        row, col = board.cell_of(int(marker_id))
        out[k] = (row > 0, col < board.cols - 1, row < board.rows - 1, col > 0)
    return out
