"""The result of a rig calibration: each camera's intrinsics, the extrinsics between the
cameras with their uncertainty, and the stereo rectification of consecutive pairs.

Frames and directions (docs/conventions.md): ``extrinsics[a, b] = (R, t)`` maps a point
in camera ``a``'s frame into camera ``b``'s, ``x_b = R @ x_a + t`` (T_b_a; metres). For a
stereo pair ``left``, ``right``, ``t`` is about ``(-baseline, 0, 0)`` when right sits to
the right of left, as ``cv2.stereoCalibrate``'s ``R, T`` and Kalibr's ``T_cn_cnm1``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from artcal_ros.core.calibrate.result import CalibrationResult, DroppedView
from artcal_ros.core.camera_info import CameraInfoData

Pair = tuple[str, str]


@dataclass(frozen=True)
class Rectification:
    """The stereo rectification of one pair, in ROS camera_calibration's convention.

    Both rectified cameras share one orientation, rows of the same scene point agree
    (a horizontal pair) or columns do (a vertical pair: the second camera above or
    below the first), and both have the same focal length and principal point row.

    Attributes:
        first, second: the cameras' names.
        R1, R2: (3, 3) rotation of each camera's frame into the rectified frame (the
            CameraInfo ``R``: x_rect = R1 @ x_first).
        P1, P2: (3, 4) projection of the rectified frame into each rectified image
            (CameraInfo ``P``), pixels: ``P1 = [K' | 0]``, ``P2 = [K' | (Tx, Ty, 0)]``
            with ``Tx = -fx' * baseline`` for a horizontal pair (``Ty = -fy' * baseline``
            for a vertical one), baseline in metres.
        image_sizes: (width, height) of the first and the second camera's image, pixels
            (the rectified images have the same sizes).
        model: the cameras' lens model (``equidistant`` pairs are rectified through
            their own fisheye undistortion).
        vertical: True for a vertical pair (compare columns, not rows).
        epipolar_rms_px: RMS of the row (column, if vertical) difference of the same
            board point seen by both cameras in one frame, after rectification, pixels;
            over the points inside both rectified images (the first camera's size).
        epipolar_points: number of such corresponding points.
    """

    first: str
    second: str
    R1: np.ndarray
    R2: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    image_sizes: tuple[tuple[int, int], tuple[int, int]]
    model: str
    vertical: bool
    epipolar_rms_px: float
    epipolar_points: int

    @property
    def baseline_m(self) -> float:
        """The baseline the projection matrices encode, metres (positive)."""
        col = 1 if self.vertical else 0
        return float(-self.P2[col, 3] / self.P2[col, col])


@dataclass(frozen=True)
class RigPair:
    """The extrinsics of one ordered camera pair and their 1-sigma uncertainty.

    Attributes:
        first, second: the cameras' names.
        R: (3, 3) rotation; t: (3,) translation, metres: ``x_second = R @ x_first + t``.
        baseline_m: ``|t|``, the distance between the optical centres, metres.
        baseline_std_m: 1-sigma of ``baseline_m``, metres.
        rotation_std_deg: (3,) 1-sigma of the rotation about each axis of the first
            camera's frame (x, y, z), degrees.
        translation_std_m: (3,) 1-sigma of each component of ``t``, metres.
        shared_frames: rig frames in which both cameras measure the board.
    """

    first: str
    second: str
    R: np.ndarray
    t: np.ndarray
    baseline_m: float
    baseline_std_m: float
    rotation_std_deg: np.ndarray
    translation_std_m: np.ndarray
    shared_frames: int

    @property
    def rotation_deg(self) -> float:
        """The angle of ``R``, degrees."""
        c = (float(np.trace(self.R)) - 1.0) / 2.0
        return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


@dataclass(frozen=True)
class RigResult:
    """A calibrated rig.

    Attributes:
        names: the cameras in the caller's order; the first is the reference frame.
        cameras: each camera's calibration (intrinsics from the joint solve; the quality
            figures, residuals and views are that camera's own in the joint solve;
            ``rvecs``/``tvecs`` are T_cam_board of its frames in ``frames_used``).
        extrinsics: ``(a, b) -> (R (3, 3), t (3,) metres)``, a point in ``a``'s frame to
            ``b``'s, for every ordered pair of different cameras.
        pairs: ``(a, b) -> RigPair`` (with uncertainty), for every ordered pair.
        shared_frames: ``(a, b) -> count`` of rig frames in which both measure the board,
            for every pair with ``a`` before ``b`` in ``names``.
        rectification: ``(a, b) -> Rectification`` for each consecutive pair of ``names``.
        frames_used: rig frame indices (positions in the input lists) in the final solve.
        frames_dropped: each camera's frames left out and why (``view_index`` is the
            frame index, ``reason`` starts with the camera's name; a camera's frame without
            any of the board is not listed).
        board_rvecs, board_tvecs: (F, 3) T_ref_board of each frame of ``frames_used``
            (Rodrigues, metres), the reference camera's frame.
        reprojection_rms_px: RMS residual length over every camera's points, pixels.
        points_dropped: outlier points removed in the joint solve.
        fixed_intrinsics: the intrinsics were given and held (only extrinsics and board
            poses solved).
        solve_time_s: wall time of :func:`~artcal_ros.core.calibrate.rig.calibrate_rig`.
        warnings: what the data could not pin down and what to add.
    """

    names: tuple[str, ...]
    cameras: dict[str, CalibrationResult]
    extrinsics: dict[Pair, tuple[np.ndarray, np.ndarray]]
    pairs: dict[Pair, RigPair]
    shared_frames: dict[Pair, int]
    rectification: dict[Pair, Rectification]
    frames_used: tuple[int, ...]
    frames_dropped: tuple[DroppedView, ...]
    board_rvecs: np.ndarray = field(repr=False)
    board_tvecs: np.ndarray = field(repr=False)
    reprojection_rms_px: float = float("nan")
    points_dropped: int = 0
    fixed_intrinsics: bool = False
    solve_time_s: float = 0.0
    warnings: tuple[str, ...] = ()

    @property
    def reference(self) -> str:
        """The camera whose frame the board poses are in (the first name)."""
        return self.names[0]

    @property
    def consecutive_pairs(self) -> list[Pair]:
        """``(names[i], names[i + 1])``: the pairs rectified and listed in camchain.yaml
        (Kalibr's ``T_cn_cnm1`` of ``cam{i+1}`` is ``extrinsics[names[i], names[i+1]]``)."""
        return [(self.names[i], self.names[i + 1]) for i in range(len(self.names) - 1)]

    @property
    def baseline_m(self) -> dict[Pair, float]:
        """``(a, b) -> |t|`` for every ordered pair, metres."""
        return {k: p.baseline_m for k, p in self.pairs.items()}

    @property
    def rectified_epipolar_rms_px(self) -> dict[Pair, float]:
        """``(a, b) -> `` RMS row difference after rectification, consecutive pairs, px."""
        return {k: r.epipolar_rms_px for k, r in self.rectification.items()}

    def transform(self, a: str, b: str) -> np.ndarray:
        """(4, 4) homogeneous T_b_a: a point in ``a``'s frame to ``b``'s (metres)."""
        R, t = self.extrinsics[a, b]
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        return T

    def camera_info(self, name: str) -> CameraInfoData:
        """The CameraInfo content of camera ``name``.

        A two-camera rig carries its stereo rectification (R and P of camera_calibration's
        convention); a camera of a larger rig is written as a monocular camera (R = I).
        """
        info = CameraInfoData.from_camera(self.cameras[name].camera, name)
        if len(self.names) != 2:
            return info
        rect = self.rectification[self.names[0], self.names[1]]
        first = name == rect.first
        return CameraInfoData(info.image_size, name, info.camera_matrix, info.distortion_model,
                              info.dist_coeffs, (rect.R1 if first else rect.R2).copy(),
                              (rect.P1 if first else rect.P2).copy())

    def summary(self, *, long: bool = False) -> str:
        """The rig in words: one line per pair (each camera against the reference and each
        consecutive pair: baseline, rotation, 1-sigma, shared frames, rectified epipolar
        RMS), then each camera's one-line summary; with ``long`` each camera's long one."""
        listed = [(self.reference, n) for n in self.names[1:]]
        listed += [p for p in self.consecutive_pairs if p not in listed]
        lines = [f"rig of {len(self.names)} cameras ({', '.join(self.names)}), "
                 f"{len(self.frames_used)} frames, reprojection RMS "
                 f"{self.reprojection_rms_px:.3f} px, {self.points_dropped} outlier points"
                 + (", intrinsics held" if self.fixed_intrinsics else "")]
        for a, b in listed:
            p = self.pairs[a, b]
            line = (f"{a} -> {b}: baseline {p.baseline_m:.5f} m (1-sigma {p.baseline_std_m:.2g}"
                    f" m), rotation {p.rotation_deg:.3f} deg (1-sigma "
                    f"{float(np.linalg.norm(p.rotation_std_deg)):.2g} deg), t = "
                    f"[{', '.join(f'{v:.5f}' for v in p.t)}] m, {p.shared_frames} shared frames")
            if (a, b) in self.rectification:
                line += (f", rectified epipolar RMS "
                         f"{self.rectification[a, b].epipolar_rms_px:.3f} px")
            lines.append(line)
        for n in self.names:
            text = self.cameras[n].summary(long=long)
            lines.append(f"{n}: {text}" if not long else f"{n}:\n{text}")
        lines += [f"warning: {w}" for w in self.warnings]
        return "\n".join(lines)

    def to_summary_dict(self) -> dict[str, Any]:
        """JSON-ready rig part of ``summary.json``: ``extrinsics`` (each camera against the
        reference and each consecutive pair), ``rectified_epipolar_rms_px`` (by pair name
        ``"a-b"``), and the counts; each camera's own summary is
        ``cameras[name].to_summary_dict()``."""
        listed = [(self.reference, n) for n in self.names[1:]]
        listed += [p for p in self.consecutive_pairs if p not in listed]
        extrinsics = []
        for a, b in listed:
            p = self.pairs[a, b]
            extrinsics.append({
                "from": a, "to": b, "rotation": p.R.tolist(),
                "translation": [float(v) for v in p.t], "baseline_m": p.baseline_m,
                "rotation_deg": p.rotation_deg, "shared_frames": p.shared_frames,
                "std_devs": {"rotation_deg": [float(v) for v in p.rotation_std_deg],
                             "translation_m": [float(v) for v in p.translation_std_m],
                             "baseline_m": p.baseline_std_m}})
        return {
            "cameras": list(self.names),
            "extrinsics": extrinsics,
            "rectified_epipolar_rms_px": {f"{a}-{b}": r.epipolar_rms_px
                                          for (a, b), r in self.rectification.items()},
            "shared_frames": {f"{a}-{b}": int(n) for (a, b), n in self.shared_frames.items()},
            "frames_used": [int(i) for i in self.frames_used],
            "frames_dropped": [{"index": d.view_index, "source": d.source, "reason": d.reason}
                               for d in self.frames_dropped],
            "reprojection_rms_px": self.reprojection_rms_px,
            "points_dropped": int(self.points_dropped),
            "fixed_intrinsics": self.fixed_intrinsics,
            "warnings": list(self.warnings),
            "solve_time_s": self.solve_time_s,
        }
