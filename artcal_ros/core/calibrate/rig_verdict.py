"""Whether a rig solve can be right: each connecting pair's joint fit against its cameras' own.

A rig frame's cameras see one board pose. When they do (synchronised images), the joint
solve fits each camera's points nearly as well as that camera's own calibration with a
board pose of its own in every frame. When the images of a rig frame were taken at
different instants, no single board pose fits both and the joint solve shows it: a
reprojection RMS far above the cameras' own, many points dropped as outliers, a baseline
longer than the cameras' distances to the board allow. Each is checked per connecting
pair (the pairs of the spanning tree), on the frames both cameras measure:

- ``excess``: sqrt(joint RMS^2 - own RMS^2), the part of the joint residual the shared
  board pose adds. Refused above ``max(EXCESS_REFUSE_FACTOR * own, EXCESS_REFUSE_PX)``,
  warned about above ``max(own, EXCESS_WARN_PX)``.
- the share of a camera's points the joint solve dropped as outliers beyond the share its
  own calibration dropped: refused above ``OUTLIER_SHARE_REFUSE``.
- the baseline against the triangle the cameras and the board make in each shared frame
  (camera a to the centre of the points a sees, across the board to the centre of b's,
  to camera b), from each camera's own board poses: refused above ``BASELINE_MARGIN``
  times the median of that bound.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.calibrate.model import project
from artcal_ros.core.calibrate.rig_solve import RigObservation
from artcal_ros.core.camera import CameraModel

__all__ = ["PairCheck", "check_pairs", "observation_excess", "refusal", "warnings_of"]

EXCESS_REFUSE_FACTOR = 3.0
EXCESS_REFUSE_PX = 0.5
EXCESS_WARN_PX = 0.1
OUTLIER_SHARE_REFUSE = 0.05
BASELINE_MARGIN = 1.2
NOT_SIMULTANEOUS = ("the cameras' images of one rig frame may not show the board at the same "
                    "instant: check sync_tolerance and the drivers' stamps (image folders: "
                    "that the files pair up in sorted order, none missing in one camera)")


@dataclass(frozen=True)
class PairCheck:
    """The figures of one connecting pair.

    Attributes:
        first, second: the cameras.
        frames: rig frames both measure in the joint solve.
        joint_rms_px: RMS of both cameras' residuals in those frames, joint solve, pixels.
        own_rms_px: the same points' RMS with each camera's own calibration and board
            poses, pixels.
        own_each_px: (first, second) own RMS of each camera alone, pixels.
        outlier_share: (first, second) share of each camera's points the joint solve
            dropped as outliers, beyond the share its own calibration dropped.
        baseline_m: the joint solve's baseline, metres.
        baseline_bound_m: median over the shared frames of the longest baseline the
            cameras' own distances to the board allow, metres.
        median_frame_excess_px: the median over the shared frames of each frame's excess
            (joint over own RMS, as :attr:`excess_px`), pixels: high when most frames
            disagree, which dropping outliers cannot mend.
        frame_excess_px: rig frame index -> that frame's excess, pixels.
    """

    first: str
    second: str
    frames: int
    joint_rms_px: float
    own_rms_px: float
    own_each_px: tuple[float, float]
    outlier_share: tuple[float, float]
    baseline_m: float
    baseline_bound_m: float
    median_frame_excess_px: float
    frame_excess_px: dict[int, float]

    @property
    def excess_px(self) -> float:
        """The part of the joint RMS the shared board poses add, pixels."""
        return float(np.sqrt(max(self.joint_rms_px ** 2 - self.own_rms_px ** 2, 0.0)))

    @property
    def limit_px(self) -> float:
        """The most excess a good rig shows, pixels."""
        return max(EXCESS_REFUSE_FACTOR * self.own_rms_px, EXCESS_REFUSE_PX)

    def hopeless(self) -> bool:
        """Most shared frames disagree beyond what a good rig shows: no outlier rejection
        will mend it."""
        return not self.median_frame_excess_px <= max(
            EXCESS_REFUSE_FACTOR * self.own_rms_px, EXCESS_REFUSE_PX)

    def problems(self) -> list[str]:
        """What makes this pair's result wrong, in words (empty: nothing)."""
        out = []
        if not self.excess_px <= self.limit_px:
            out.append(f"reprojection RMS {self.joint_rms_px:.3g} px over {self.frames} rig "
                       f"frames where each camera alone fits the same points to "
                       f"{self.own_each_px[0]:.3g} px ({self.first}) and "
                       f"{self.own_each_px[1]:.3g} px ({self.second}); a good rig adds under "
                       f"{self.limit_px:.2g} px")
            bad = sorted(f for f, e in self.frame_excess_px.items() if not e <= self.limit_px)
            if len(bad) < len(self.frame_excess_px):
                out.append(f"{len(bad)} of {self.frames} frames disagree (frame"
                           f"{'s' if len(bad) > 1 else ''} {', '.join(map(str, bad[:10]))}"
                           f"{', ...' if len(bad) > 10 else ''})")
        for n, share in zip((self.first, self.second), self.outlier_share, strict=True):
            if share > OUTLIER_SHARE_REFUSE:
                out.append(f"{100 * share:.0f} % of {n}'s points dropped as outliers (its own "
                           f"calibration: fewer; a good rig: under "
                           f"{100 * OUTLIER_SHARE_REFUSE:.0f} %)")
        if self.baseline_m > BASELINE_MARGIN * self.baseline_bound_m:
            out.append(f"baseline {self.baseline_m:.3g} m, longer than the cameras' distances "
                       f"to the board allow (at most {self.baseline_bound_m:.3g} m)")
        return out

    def warning(self) -> str | None:
        """A milder disagreement between the cameras, in words, or None."""
        if self.problems() or self.excess_px <= max(self.own_rms_px, EXCESS_WARN_PX):
            return None
        return (f"{self.first}-{self.second}: the shared board poses add {self.excess_px:.2f} "
                f"px to the cameras' own {self.own_rms_px:.2f} px RMS; the images of a rig "
                "frame may be slightly apart in time (check the stamps) or the board moved "
                "during exposure")


def _centre_in_board(pose: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    R = cv2.Rodrigues(np.asarray(pose[0], np.float64))[0]
    return -R.T @ np.asarray(pose[1], np.float64)


def observation_excess(residuals: Sequence[np.ndarray], obs: Sequence[RigObservation],
                       frames: Sequence[int], own_cameras: Sequence[CameraModel],
                       own_poses: Sequence[Mapping[int, tuple[np.ndarray, np.ndarray]]]
                       ) -> list[tuple[float, float]]:
    """Per observation, (excess, own RMS), pixels: how much worse the rig's board pose fits
    it than the camera's own pose of that frame (sqrt of the difference of mean squares),
    and the own pose's RMS.

    Args:
        residuals: per observation, (M, 2) pixels, under the rig's poses.
        obs, frames: the observations and the rig frame index of each solve frame.
        own_cameras, own_poses: per camera position, its own calibration and its own
            T_cam_board by rig frame index.
    """
    out = []
    for o, r in zip(obs, residuals, strict=True):
        cam = own_cameras[o.camera]
        pose = own_poses[o.camera][frames[o.frame]]
        own = o.view.image_points - project(o.view.object_points, pose[0], pose[1], cam.K,
                                            cam.dist, cam.model)
        own_sq = float(np.mean(np.sum(own ** 2, axis=1)))
        joint_sq = float(np.mean(np.sum(np.asarray(r) ** 2, axis=1)))
        out.append((float(np.sqrt(max(joint_sq - own_sq, 0.0))) if np.isfinite(joint_sq)
                    else float("inf"), float(np.sqrt(own_sq))))
    return out


def check_pairs(names: Sequence[str], tree: Sequence[tuple[str, str]],
                residuals: Sequence[np.ndarray], obs: Sequence[RigObservation],
                frames: Sequence[int],
                own_cameras: Mapping[str, CameraModel],
                own_poses: Mapping[str, Mapping[int, tuple[np.ndarray, np.ndarray]]],
                baselines: Mapping[tuple[str, str], float],
                joint_dropped: Mapping[str, int],
                own_dropped_share: Mapping[str, float]) -> list[PairCheck]:
    """The figures of every connecting pair (``tree``) of a finished joint solve.

    Args:
        names: the cameras in order; tree: (a, b) connecting pairs.
        residuals: per observation, (M, 2) pixels, of the joint solve (or its start).
        obs, frames: the observations and the rig frame index of each solve frame.
        own_cameras: each camera's own calibration (or given intrinsics).
        own_poses: camera -> rig frame index -> its own T_cam_board (rvec, tvec).
        baselines: (a, b) -> the joint solve's baseline, metres.
        joint_dropped: camera -> points the joint solve dropped as outliers.
        own_dropped_share: camera -> share of its points its own calibration dropped.
    """
    index = {n: k for k, n in enumerate(names)}
    by_cam: dict[int, dict[int, tuple[RigObservation, np.ndarray]]] = {}
    for o, r in zip(obs, residuals, strict=True):
        by_cam.setdefault(o.camera, {})[frames[o.frame]] = (o, r)
    totals = {n: sum(len(o.view) for o, _ in by_cam.get(index[n], {}).values())
              for n in names}
    share = {n: max(joint_dropped.get(n, 0) / max(totals[n] + joint_dropped.get(n, 0), 1)
                    - own_dropped_share.get(n, 0.0), 0.0) for n in names}
    out = []
    for a, b in tree:
        seen_a, seen_b = by_cam.get(index[a], {}), by_cam.get(index[b], {})
        shared = sorted(set(seen_a) & set(seen_b))
        joint_sq: list[np.ndarray] = []
        own_sq: dict[str, list[np.ndarray]] = {a: [], b: []}
        bounds = []
        frame_excess: dict[int, float] = {}
        for f in shared:
            ends = []
            for n, seen in ((a, seen_a), (b, seen_b)):
                o, r = seen[f]
                joint_sq.append(np.sum(r ** 2, axis=1))
                cam, pose = own_cameras[n], own_poses[n][f]
                own = o.view.image_points - project(o.view.object_points, pose[0], pose[1],
                                                    cam.K, cam.dist, cam.model)
                own_sq[n].append(np.sum(own ** 2, axis=1))
                ends.append((_centre_in_board(pose), o.view.object_points.mean(axis=0)))
            frame_excess[f] = float(np.sqrt(max(
                np.mean(np.concatenate(joint_sq[-2:])) - np.mean(np.concatenate(
                    [own_sq[a][-1], own_sq[b][-1]])), 0.0)))
            (ca, pa), (cb, pb) = ends
            bounds.append(float(np.linalg.norm(ca - pa) + np.linalg.norm(pa - pb)
                                + np.linalg.norm(pb - cb)))
        if not shared:
            continue
        each = tuple(float(np.sqrt(np.mean(np.concatenate(own_sq[n])))) for n in (a, b))
        out.append(PairCheck(
            a, b, len(shared), float(np.sqrt(np.mean(np.concatenate(joint_sq)))),
            float(np.sqrt(np.mean(np.concatenate(own_sq[a] + own_sq[b])))),
            (each[0], each[1]), (share[a], share[b]), float(baselines[a, b]),
            float(np.median(bounds)), float(np.median(list(frame_excess.values()))),
            frame_excess))
    return out


def refusal(checks: Sequence[PairCheck]) -> str | None:
    """The reason to refuse the rig (every failing pair, what is wrong, what to do), or
    None when every pair is sound."""
    failing = [f"{c.first}-{c.second}: " + "; ".join(p)
               for c in checks if (p := c.problems())]
    if not failing:
        return None
    return "the rig solve is refused: " + " | ".join(failing) + "; " + NOT_SIMULTANEOUS


def warnings_of(checks: Sequence[PairCheck]) -> list[str]:
    """The pairs whose cameras disagree more than noise explains, but not enough to refuse."""
    return [w for c in checks if (w := c.warning()) is not None]
