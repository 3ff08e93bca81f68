"""Exact rig detections for the rig tests: the board's marker corners projected through each
camera of a renderer rig (:mod:`artcal_ros.synth.rig`), with Gaussian corner noise."""

from __future__ import annotations

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.synth import Camera
from artcal_ros.synth.poses import Pose, marker_truth
from artcal_ros.synth.rig import Rig, rig_poses

BOARD = Board.from_params({"board.cols": 10, "board.rows": 7, "board.marker_length": 0.03,
                           "board.marker_separation": 0.01})


def diagonal_centers(corners: np.ndarray) -> np.ndarray:
    """Centres as a detector without a lens model measures them: (M, 4, 2) -> (M, 2)."""
    h = np.concatenate([corners, np.ones((*corners.shape[:2], 1))], axis=2)
    c = np.cross(np.cross(h[:, 0], h[:, 2]), np.cross(h[:, 1], h[:, 3]))
    return c[:, :2] / c[:, 2:3]


def rig_detections(rig: Rig, poses: list[Pose], rng: np.random.Generator, noise_px: float,
                   board: Board = BOARD) -> dict[str, list[Detections]]:
    """Per camera, one Detections per frame: the markers wholly inside its image."""
    out: dict[str, list[Detections]] = {n: [] for n in rig.names}
    for k, first_board in enumerate(poses):
        for n in rig.names:
            cam = rig.camera(n)
            corners, _, inside, _ = marker_truth(board, cam, *rig.camera_pose(n, first_board))
            noisy = corners[inside] + rng.normal(0.0, noise_px, corners[inside].shape)
            out[n].append(Detections(board.ids[inside], noisy, diagonal_centers(noisy),
                                     cam.size, source=f"{n}/{k:03d}.png"))
    return out


def make_rig(name: str, preset: str, frames: int, seed: int, noise_px: float = 0.03, *,
             board: Board = BOARD, partial_fraction: float = 0.3
             ) -> tuple[Rig, dict[str, list[Detections]]]:
    """A renderer rig of ``preset`` cameras and its exact detections over random frames."""
    rig = Rig.preset(name, Camera.preset(preset))
    rng = np.random.default_rng(seed)
    poses = rig_poses(board, rig, frames, rng, partial_fraction=partial_fraction)
    return rig, rig_detections(rig, poses, rng, noise_px, board)


def rotation_error_deg(R_true: np.ndarray, R_est: np.ndarray) -> float:
    """Angle of R_true^T R_est, degrees (from its skew part: exact for small angles, where
    cv2.Rodrigues rounds below 1e-5 rad to zero)."""
    d = R_true.T @ R_est
    s = 0.5 * np.array([d[2, 1] - d[1, 2], d[0, 2] - d[2, 0], d[1, 0] - d[0, 1]])
    return float(np.degrees(np.arctan2(np.linalg.norm(s), 0.5 * (np.trace(d) - 1.0))))
