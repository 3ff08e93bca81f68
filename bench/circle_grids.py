"""Circle grids (``circles``, ``acircles``) against renderer truth, with OpenCV on the same frames.

Run by ``python -m bench.boards`` (its "Circle grids" table). Whole-board views drawn by
``random_poses`` for each camera and condition of bench.boards; for each method, the share of
views found and the RMS distance of its centres from the true images of the circles' centres:

- artcal_ros: ``Detector.detect`` (OpenCV's grid, our edge fit in linear light, the centre
  as the pole of the vanishing line, a per-view division lens);
- ellipse centre: the same edge points and conic fit, but the conic's own centre taken as
  the circle's (what an ellipse fit without the perspective correction gives): the
  perspective bias the correction removes;
- OpenCV: ``findCirclesGrid`` with its default blob detector and flags (its blob
  centroids), matched to the nearest true centre.

A point of artcal_ros more than 1 px from the true image of its id is a wrong id. The 9 x 6
symmetric grid looks the same turned by a half turn; views where artcal_ros numbers it from
the far end (its documented rule: point 0 is the one nearer the image's top-left) are
counted as "half turn" and measured with the turned ids. (The 4 x 11 asymmetric grid has no
such symmetry: every id of it is exact.)
"""

from __future__ import annotations

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector
from artcal_ros.core.detect.circle_grid import find_circle_grid, orient_grid
from artcal_ros.core.detect.circles import measure_circle
from artcal_ros.core.detect.image import to_gray8
from artcal_ros.core.detect.tone import ToneCurve
from artcal_ros.synth import Camera, Photometry, random_poses, render_view

CIRCLES = Board(board_type="circles", cols=9, rows=6, square_length=0.04)
ACIRCLES = Board(board_type="acircles", cols=4, rows=11, square_length=0.03)


def _rms(errors: list[np.ndarray]) -> float:
    e = np.concatenate(errors) if errors else np.zeros(0)
    return float(np.sqrt(np.mean(e ** 2))) if e.size else float("nan")


def ellipse_centres(image: np.ndarray, board: Board) -> np.ndarray:
    """(N, 2) px: each circle's fitted conic's own centre (NaN where the fit failed), in the
    board's id order; empty when the grid is not found."""
    grid = find_circle_grid(to_gray8(image), board)
    oriented = None if grid is None else orient_grid(grid, board)
    if oriented is None or board.circles is None:
        return np.zeros((0, 2))
    g, H = oriented
    lin = ToneCurve("power", 2.2).linearise(image).astype(np.float32)
    out = np.full((len(board.point_ids), 2), np.nan)
    for k, start in enumerate(g.reshape(-1, 2)):
        C, rms, _ = measure_circle(lin, start, H, board.object_points()[k, :2],
                                   board.circles.radius)
        if np.isfinite(rms):
            c = np.linalg.solve(C, np.array([0.0, 0.0, 1.0]))
            out[k] = c[:2] / c[2]
    return out


def circle_grid(board: Board, camera: str, photometry: Photometry, views: int,
                seed: int) -> dict[str, str]:
    """Found share, centre RMS per method, wrong ids and half turns on whole-board views."""
    cam = Camera.preset(camera)
    rng = np.random.default_rng(seed)
    detector = Detector(board)
    flags = (cv2.CALIB_CB_ASYMMETRIC_GRID if board.board_type == "acircles"
             else cv2.CALIB_CB_SYMMETRIC_GRID)
    names = ("artcal_ros", "ellipse centre", "OpenCV")
    found = dict.fromkeys(names, 0)
    errors: dict[str, list[np.ndarray]] = {k: [] for k in names}
    wrong = turned = 0
    n = 0
    for r, t in random_poses(board, cam, views, rng, partial_fraction=0.0):
        view = render_view(board, cam, r, t, photometry=photometry, rng=rng)
        n += 1
        truth = view.points_px
        det = detector.detect(view.image)
        if len(det.point_ids):
            found["artcal_ros"] += 1
            ids = det.point_ids
            e = np.linalg.norm(det.points_px - truth[ids], axis=1)
            flipped = board.point_ids[::-1][ids]
            e_turn = np.linalg.norm(det.points_px - truth[flipped], axis=1)
            if np.median(e_turn) < np.median(e):
                turned += 1
                e, ids = e_turn, flipped
            wrong += int((e > 1.0).sum())
            errors["artcal_ros"].append(e[e <= 1.0])
            ell = ellipse_centres(view.image, board)
            if len(ell):
                ok = np.isfinite(ell[det.point_ids, 0])
                found["ellipse centre"] += 1
                errors["ellipse centre"].append(
                    np.linalg.norm(ell[det.point_ids][ok] - truth[ids][ok], axis=1))
        ok_cv, centres = cv2.findCirclesGrid(view.image, (board.cols, board.rows), flags=flags)
        if ok_cv and centres is not None:
            found["OpenCV"] += 1
            c = centres.reshape(-1, 1, 2)
            errors["OpenCV"].append(np.linalg.norm(c - truth[None], axis=2).min(axis=1))
    out = {k: f"{found[k]}/{n} {_rms(errors[k]):.4f}" for k in names}
    out["wrong ids"] = str(wrong)
    out["half turn"] = str(turned)
    return out
