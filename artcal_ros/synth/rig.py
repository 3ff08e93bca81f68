"""Camera rigs for the renderer: synchronised cameras of exact extrinsics, and rig poses.

Two rigs, named as ``artcal synth --rig`` names them::

    rig = Rig.preset("stereo", Camera.preset("webcam"))   # left, right: 12 cm baseline
    rig = Rig.preset("trio", Camera.preset("webcam"))     # cam0 cam1 cam2, fanned out
    poses = rig_poses(board, rig, 20, np.random.default_rng(0))   # T_first_board per frame
    for name in rig.names:
        rvec, tvec = rig.camera_pose(name, poses[0])    # T_name_board

``stereo``: ``left`` and ``right``, right's centre 0.12 m along left's x axis, its optical axis
turned 0.38 deg from left's. ``trio``: ``cam0`` ``cam1`` ``cam2`` side by side 0.15 m apart,
the outer two turned outwards (left and right) by half the lens's field plus 5 deg (35 to
85 deg, :func:`trio_yaw_deg`), so each outer camera shares part of its field with ``cam1``
and none in front of the rig with the other: the board connects them through ``cam1``.
The cameras after the first differ a little from the given camera (focal length, principal
point, distortion), as two copies of one camera model do.

Frames: the rig stands still and the board is held in front of it, aimed at one camera or
between two neighbours (a view the pair shares), as close as a partial view or as far as a
whole-board view; some frames leave a camera with part of the board or none of it.

Extrinsics: T_b_a = (R, t) maps a point in camera a's frame into camera b's,
``p_b = R p_a + t`` (docs/conventions.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.errors import ParameterError
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.poses import Pose, ease_between, feature_visibility, random_poses

RIGS = ("stereo", "trio")
STEREO_BASELINE_M = 0.12
TRIO_SPACING_M = 0.15
TRIO_YAW_DEG = 35.0   # at least; more for a lens wider than 60 degrees across
# a view is placed again (up to this many times) until its aimed cameras see the board
_ATTEMPTS = 200


def _rotation(rotvec_deg: tuple[float, float, float]) -> np.ndarray:
    return np.asarray(cv2.Rodrigues(np.radians(np.asarray(rotvec_deg, np.float64)))[0])


def _matrix(rvec: np.ndarray) -> np.ndarray:
    return np.asarray(cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0])


def _rvec(R: np.ndarray) -> np.ndarray:
    return np.asarray(cv2.Rodrigues(np.asarray(R, np.float64))[0]).ravel()


def compose(a: Pose, b: Pose) -> Pose:
    """T_x_z = T_x_y (``a``) after T_y_z (``b``), each (rvec (3,), tvec (3,) metres)."""
    Ra = _matrix(a[0])
    t = Ra @ np.asarray(b[1], np.float64).reshape(3) + np.asarray(a[1], np.float64).reshape(3)
    return _rvec(Ra @ _matrix(b[0])), t


def invert(a: Pose) -> Pose:
    """T_y_x of T_x_y, each (rvec (3,), tvec (3,) metres)."""
    R = _matrix(a[0])
    return _rvec(R.T), -R.T @ np.asarray(a[1], np.float64).reshape(3)


def half_field_deg(cam: Camera) -> float:
    """Half the horizontal field of view (the image's left and right edge, mid-height), deg."""
    u = np.array([0.0, cam.width - 1.0])
    v = np.full(2, (cam.height - 1) / 2.0)
    rays = np.asarray(cam.rays(u, v)[0], np.float64)
    angles = np.degrees(np.arctan2(np.hypot(rays[:, 0], rays[:, 1]), rays[:, 2]))
    return float(angles.max())


def trio_yaw_deg(cam: Camera) -> float:
    """How far the trio's outer cameras turn outwards: enough that their fields do not meet
    in front of the rig (half the field plus 5 deg), at least 35 and at most 85 deg."""
    return float(np.clip(half_field_deg(cam) + 5.0, TRIO_YAW_DEG, 85.0))


def _variant(cam: Camera, index: int) -> Camera:
    """The rig's camera ``index``: the first as given, the others a copy of the same model
    with a slightly different focal length, principal point and distortion."""
    if index == 0:
        return cam
    s = 1.0 if index % 2 else -1.0
    K = cam.K.copy()
    K[0, 0] *= 1 + 0.004 * s
    K[1, 1] *= 1 + 0.0035 * s
    K[0, 2] += 2.7 * s
    K[1, 2] -= 1.9 * s
    dist = cam.dist * (1 - 0.03 * s)
    return Camera(cam.model, K, dist, cam.size)


@dataclass(frozen=True)
class Rig:
    """Cameras at fixed places on one rigid mount.

    Attributes:
        name: ``stereo`` | ``trio``.
        names: the cameras' names; the first is the reference of the extrinsics.
        cameras: (n,) the cameras, in ``names`` order.
        rig_poses: (n,) T_cam_rig of each camera (rig: a frame of the mount, x right, y down,
            z forward).
        apart: pairs of cameras that never see the board in the same frame.
    """

    name: str
    names: tuple[str, ...]
    cameras: tuple[Camera, ...]
    rig_poses: tuple[Pose, ...]
    apart: tuple[tuple[str, str], ...] = ()

    @classmethod
    def preset(cls, name: str, camera: Camera) -> Rig:
        """The rig ``name`` (one of :data:`RIGS`) built of copies of ``camera``."""
        if name == "stereo":
            names: tuple[str, ...] = ("left", "right")
            # (rotation of the camera in the rig, deg as a rotation vector; centre, metres)
            places = [((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
                      ((0.15, -0.35, 0.12), (STEREO_BASELINE_M, 0.0, 0.0))]
        elif name == "trio":
            names = ("cam0", "cam1", "cam2")
            yaw = trio_yaw_deg(camera)
            places = [((0.4, -yaw, 0.3), (-TRIO_SPACING_M, 0.0, 0.0)),
                      ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0)),
                      ((-0.3, yaw, -0.2), (TRIO_SPACING_M, 0.0, 0.002))]
        else:
            raise ParameterError(f"--rig: {name!r} is not one of {', '.join(RIGS)}")
        poses = []
        for rot_deg, centre in places:
            poses.append(invert((_rvec(_rotation(rot_deg)), np.array(centre))))
        cams = tuple(_variant(camera, i) for i in range(len(names)))
        apart = (("cam0", "cam2"),) if name == "trio" else ()
        return cls(name, names, cams, tuple(poses), apart)

    def camera(self, name: str) -> Camera:
        """The camera called ``name``."""
        return self.cameras[self.names.index(name)]

    def pose_in_first(self, name: str) -> Pose:
        """T_name_first: a point in the first camera's frame -> camera ``name``'s frame."""
        return compose(self.rig_poses[self.names.index(name)], invert(self.rig_poses[0]))

    def extrinsics(self, a: str, b: str) -> tuple[np.ndarray, np.ndarray]:
        """T_b_a as (R (3, 3), t (3,) metres): a point in a's frame -> b's frame."""
        rvec, t = compose(self.rig_poses[self.names.index(b)],
                          invert(self.rig_poses[self.names.index(a)]))
        return _matrix(rvec), np.asarray(t)

    def camera_pose(self, name: str, first_board: Pose) -> Pose:
        """T_name_board from T_first_board (the board seen by the rig's first camera)."""
        return compose(self.pose_in_first(name), first_board)

    def aims(self) -> list[tuple[str, ...]]:
        """Where a frame's board is held: at each camera alone, or between neighbours
        (listed twice: the views a pair shares are the ones that tie the rig together)."""
        pairs = [self.names[i:i + 2] for i in range(len(self.names) - 1)]
        return [(n,) for n in self.names] + pairs * 2

    def _aim_pose(self, aim: tuple[str, ...]) -> Pose:
        """T_aim_rig of a camera, or of a camera midway between two (orientation halved)."""
        if len(aim) == 1:
            return self.rig_poses[self.names.index(aim[0])]
        a, b = (invert(self.rig_poses[self.names.index(n)]) for n in aim)   # T_rig_cam
        Ra, Rb = _matrix(a[0]), _matrix(b[0])
        R_rig_mid = Ra @ _matrix(_rvec(Ra.T @ Rb) * 0.5)
        return invert((_rvec(R_rig_mid), 0.5 * (a[1] + b[1])))


def _sees(board: Board, cam: Camera, pose: Pose, min_inside: int) -> bool:
    inside, size = feature_visibility(board, cam, *pose)
    return bool(inside.sum() >= min_inside and np.median(size[inside]) >= 8.0)


def _fits(board: Board, rig: Rig, first_board: Pose, aim: tuple[str, ...],
          min_inside: int) -> bool:
    """Every aimed camera sees the board, and no pair kept apart sees any of it together."""
    if not all(_sees(board, rig.camera(a), rig.camera_pose(a, first_board), min_inside)
               for a in aim):
        return False
    return not any(all(feature_visibility(board, rig.camera(c),
                                          *rig.camera_pose(c, first_board))[0].any()
                       for c in pair)
                   for pair in rig.apart)


def rig_poses(board: Board, rig: Rig, n: int, rng: np.random.Generator, *,
              partial_fraction: float = 0.3, motion: str = "random",
              frames_per_key: int = 10, min_inside: int = 8) -> list[Pose]:
    """``n`` poses T_first_board of a board held in front of the rig.

    Each view (each key view with ``motion="smooth"``) is aimed at one camera or between two
    neighbours (:meth:`Rig.aims`, in a shuffled cycle) and placed as
    :func:`~artcal_ros.synth.poses.random_poses` places a single camera's view; it is kept
    when every aimed camera sees ``min_inside`` markers (points) of at least 8 px (a
    whole-board view that cannot be placed so becomes a close one). The other
    cameras see what they see (part of the board or none of it), except that the pairs
    :attr:`Rig.apart` never both see some of it.

    Args:
        board: the board.
        rig: the rig.
        n: frames, >= 0.
        rng: the random source.
        partial_fraction: share of views so close that the board overfills the aimed view.
        motion: ``random`` (independent views) or ``smooth`` (eased between key views,
            ``frames_per_key`` apart; views between keys are not checked).
        min_inside: markers (points) an aimed camera must see wholly.

    Returns:
        list of (rvec (3,), tvec (3,) metres), T_first_board.
    """
    if motion not in ("random", "smooth"):
        raise ParameterError(f"--motion: {motion!r} is not one of random, smooth")
    if n <= 0:
        return []
    n_keys = n if motion == "random" else max(2, math.ceil((n - 1) / frames_per_key) + 1)
    cycle = rig.aims()
    n_partial = round(n_keys * partial_fraction)
    partial = np.array([True] * n_partial + [False] * (n_keys - n_partial))
    rng.shuffle(partial)
    first_rig = rig.rig_poses[0]
    keys: list[Pose] = []
    order: list[tuple[str, ...]] = []
    for k in range(n_keys):
        if not order:
            order = [cycle[i] for i in rng.permutation(len(cycle))]
        aim = order.pop()
        rig_aim = invert(rig._aim_pose(aim))   # T_rig_aim
        for attempt in range(_ATTEMPTS):
            # a whole-board view a pair kept apart would both see becomes a closer one
            close = partial[k] or attempt >= _ATTEMPTS // 4
            aim_board = random_poses(board, rig.camera(aim[0]), 1, rng,
                                     partial_fraction=1.0 if close else 0.0)[0]
            first_board = compose(first_rig, compose(rig_aim, aim_board))
            if _fits(board, rig, first_board, aim, min_inside):
                break
        else:
            raise ParameterError(
                f"rig_poses: could not place a view aimed at {' and '.join(aim)} of the "
                f"{rig.name} rig in {_ATTEMPTS} tries; the board may be too large or too "
                "small for these cameras")
        keys.append(first_board)
    return keys if motion == "random" else ease_between(keys, n, frames_per_key=frames_per_key)
