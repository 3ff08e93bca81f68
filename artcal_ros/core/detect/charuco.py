"""ChArUco corners: placed by the verified markers around them, refined by the saddle fit.

Every inner corner of a ChArUco board touches two white squares, each holding a marker.
A corner is predicted from the homography of the markers found among those two (their
refined corners, board -> image); where neither was found, from the markers of the
squares around it (up to two squares away). The prediction also gives the local image of
the board's axes, which lays out the saddle fit's window in board coordinates: the black
squares whole, the white ones only along the band of paper between the edges and the
marker (the marker's quiet zone). A corner is kept when the fit converges within a third
of a square of its prediction with the board's polarity; its id is the board's, so a
corner is never given a wrong id unless a marker had one (which verification prevents).

Partial views are the rule: any corner near a found marker is measured.
"""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.saddle import fit_saddles

REACH_SQUARES = 2   # how far (in squares) a marker may be from a corner it predicts


def _homography(obj: np.ndarray, img: np.ndarray) -> np.ndarray | None:
    """(3, 3) board (metres) -> image homography of >= 4 correspondences, or None."""
    if len(obj) == 4:
        H = cv2.getPerspectiveTransform(obj.astype(np.float32), img.astype(np.float32))
    else:
        H, _ = cv2.findHomography(obj, img, 0)
    return None if H is None or not np.all(np.isfinite(H)) else np.asarray(H, np.float64)


def _map(H: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The image of board point p (2,) and the Jacobian d(image)/d(board) (2, 2) there."""
    q = H @ np.array([p[0], p[1], 1.0])
    x = q[:2] / q[2]
    Jac = (H[:2, :2] - np.outer(x, H[2, :2])) / q[2]
    return x, Jac


def predict_corners(board: Board, marker_ids: np.ndarray, marker_corners_px: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the found markers put the board's corners.

    Args:
        board: a ``charuco`` board.
        marker_ids: (N,) found marker ids.
        marker_corners_px: (N, 4, 2) their corners TL, TR, BR, BL, pixels.

    Returns:
        (corner ids (K,), predicted positions (K, 2) pixels, axes (K, 2, 2): the image of
        one square along the board's x and y axes at each corner).
    """
    chess = board.chess
    assert chess is not None
    found = {int(i): k for k, i in enumerate(marker_ids)}
    obj_all = board.object_corners(np.asarray(marker_ids, dtype=np.int64))[:, :, :2]
    at_square = chess.marker_at_square
    ids_out, pos_out, axes_out = [], [], []
    for cid, (r, c) in zip(board.point_ids, chess.corner_cells(board.point_ids), strict=True):
        use: list[int] = []
        for reach in (1, REACH_SQUARES):
            # the squares (r .. r+1, c .. c+1) touch corner (r, c); widen by reach - 1
            r0, r1 = max(r + 1 - reach, 0), min(r + reach + 1, chess.squares_y)
            c0, c1 = max(c + 1 - reach, 0), min(c + reach + 1, chess.squares_x)
            near = at_square[r0:r1, c0:c1].ravel()
            use = [found[m + board.first_id] for m in near
                   if m >= 0 and m + board.first_id in found]
            if use:
                break
        if not use:
            continue
        H = _homography(obj_all[use].reshape(-1, 2), marker_corners_px[use].reshape(-1, 2))
        if H is None:
            continue
        p_board = board.object_points(np.array([cid]))[0, :2]
        x, Jac = _map(H, p_board)
        ids_out.append(int(cid))
        pos_out.append(x)
        axes_out.append(Jac * board.square_length)
    if not ids_out:
        return np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2, 2))
    return np.array(ids_out, np.int64), np.array(pos_out), np.array(axes_out)


def charuco_corners(lin: np.ndarray, board: Board, marker_ids: np.ndarray,
                    marker_corners_px: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ChArUco corners of one image, from its verified markers.

    Args:
        lin: (H, W) float linear-light grey.
        board: a ``charuco`` board.
        marker_ids: (N,) verified marker ids; marker_corners_px: (N, 4, 2) their corners.

    Returns:
        (point_ids (M,) int64 ascending, points_px (M, 2), point_sigma_px (M,)).
    """
    ids, guess, axes = predict_corners(board, marker_ids, marker_corners_px)
    if len(ids) == 0:
        return ids, guess, np.zeros(0)
    h, w = lin.shape
    inside = ((guess[:, 0] >= 1) & (guess[:, 0] <= w - 2) & (guess[:, 1] >= 1)
              & (guess[:, 1] <= h - 2) & (np.abs(np.linalg.det(axes)) > 16.0))
    ids, guess, axes = ids[inside], guess[inside], axes[inside]
    chess = board.chess
    assert chess is not None
    fit = fit_saddles(lin, guess, axes, chess.corner_black_diagonal(ids),
                      band=board.quiet_zone_m / board.square_length)
    ok = fit.ok
    return ids[ok], fit.points_px[ok], fit.sigma_px[ok]
