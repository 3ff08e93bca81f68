"""The start of a rig solve: which cameras are connected through shared frames, and the
extrinsics and board poses to start the joint bundle adjustment from.

The start cannot diverge: every camera's board poses come from its own calibration, and
each extrinsic is the robust median of the relative poses over the frames both cameras
measure, chained along the pairs that share the most frames.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import cv2
import numpy as np

from artcal_ros.core.errors import CalibrationError

Pair = tuple[str, str]
MIN_SHARED_FRAMES = 3  # a pair connects the rig when both cameras measure the board this often


def shared_frame_counts(names: Sequence[str],
                        seen: Mapping[str, set[int]]) -> dict[Pair, int]:
    """``(a, b) -> `` number of frames both measure, for every pair with ``a`` before ``b``.

    Args:
        names: the cameras in order.
        seen: per camera, the rig frame indices in which it measures the board.
    """
    return {(a, b): len(seen[a] & seen[b]) for i, a in enumerate(names) for b in names[i + 1:]}


def _count(shared: Mapping[Pair, int], a: str, b: str) -> int:
    return int(shared.get((a, b), shared.get((b, a), 0)))


def spanning_tree(names: Sequence[str], shared: Mapping[Pair, int], *,
                  min_shared: int = MIN_SHARED_FRAMES) -> list[Pair]:
    """The pairs that connect every camera to ``names[0]``, those sharing the most frames
    first (a maximum spanning tree grown from the reference): ``(parent, child)``, parents
    before children. Cameras that cannot be reached are left out."""
    reached = [names[0]]
    tree: list[Pair] = []
    while True:
        best: tuple[int, str, str] | None = None
        for a in reached:
            for b in names:
                n = _count(shared, a, b)
                if b not in reached and n >= min_shared and (best is None or n > best[0]):
                    best = (n, a, b)
        if best is None:
            return tree
        tree.append((best[1], best[2]))
        reached.append(best[2])


def connectivity_problem(names: Sequence[str], shared: Mapping[Pair, int], *,
                         min_shared: int = MIN_SHARED_FRAMES) -> str | None:
    """Why the cameras do not form one rig (which are cut off, each pair's shared frames,
    what to show), or None when every camera is connected to the first."""
    tree = spanning_tree(names, shared, min_shared=min_shared)
    reached = {names[0], *(b for _, b in tree)}
    apart = [n for n in names if n not in reached]
    if not apart:
        return None
    counts = ", ".join(f"{a}-{b} {_count(shared, a, b)}" for i, a in enumerate(names)
                       for b in names[i + 1:])
    # The connected camera that shares most with the cut-off ones is the one to pair with.
    # (on a tie, the nearest in the cameras' order: neighbours in a list are usually
    # neighbours on the mount)
    first = names.index(apart[0])
    partner = max(reached, key=lambda r: (sum(_count(shared, r, n) for n in apart),
                                          -abs(names.index(r) - first)))
    which = " and ".join(apart)
    verb = "is" if len(apart) == 1 else "are"
    return (f"camera{'s' if len(apart) > 1 else ''} {which} {verb} not connected to the rig: "
            f"a pair connects when both cameras measure the board in at least {min_shared} "
            f"frames (shared frames: {counts}); hold the board where {apart[0]} and "
            f"{partner} both see part of it (they need not see the same markers) in a few "
            "more frames")


def _to_matrix(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, np.float64))[0]
    T[:3, 3] = np.asarray(tvec, np.float64).ravel()
    return T


def _to_vector(T: np.ndarray) -> np.ndarray:
    return np.concatenate([cv2.Rodrigues(T[:3, :3])[0].ravel(), T[:3, 3]])


def robust_mean_transform(candidates: Sequence[np.ndarray]) -> np.ndarray:
    """(4, 4) the robust centre of several estimates of one rigid transform.

    The candidate closest to all others (sum of rotation angles and of translation
    distances relative to their medians) is the centre; the candidates within three
    median deviations of it are averaged (rotations by the projection of their mean onto
    the rotations, translations by their mean).
    """
    Ts = np.asarray(candidates, dtype=np.float64)
    if len(Ts) == 1:
        return Ts[0].copy()
    Rs, ts = Ts[:, :3, :3], Ts[:, :3, 3]

    def angles(R0: np.ndarray) -> np.ndarray:
        c = (np.einsum("kij,ij->k", Rs, R0) - 1.0) / 2.0
        return np.arccos(np.clip(c, -1.0, 1.0))

    ang = np.array([angles(R) for R in Rs])              # (K, K)
    dist = np.linalg.norm(ts[:, None] - ts[None], axis=2)
    scale_a = max(float(np.median(ang)), 1e-9)
    scale_t = max(float(np.median(dist)), 1e-12)
    centre = int(np.argmin(ang.sum(axis=1) / scale_a + dist.sum(axis=1) / scale_t))
    da, dt = ang[centre], dist[centre]
    keep = (da <= 3.0 * max(float(np.median(da)), 1e-9)) & (
        dt <= 3.0 * max(float(np.median(dt)), 1e-12))
    U, _, Vt = np.linalg.svd(Rs[keep].sum(axis=0))
    R = U @ Vt
    if np.linalg.det(R) < 0:
        U[:, -1] *= -1
        R = U @ Vt
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = ts[keep].mean(axis=0)
    return T


def initial_extrinsics(names: Sequence[str], tree: Sequence[Pair],
                       poses: Mapping[str, Mapping[int, tuple[np.ndarray, np.ndarray]]]
                       ) -> np.ndarray:
    """(N, 6) T_c_ref of every camera (rvec, tvec metres; row 0 zeros), chained along
    ``tree`` from each pair's robust median over the frames both cameras have a pose in.

    Args:
        names: the cameras; names[0] is the reference.
        tree: :func:`spanning_tree`.
        poses: per camera, frame index -> its own T_cam_board (rvec (3,), tvec (3,)).
    """
    T_c_ref = {names[0]: np.eye(4)}
    for a, b in tree:
        both = sorted(set(poses[a]) & set(poses[b]))
        cands = [_to_matrix(*poses[b][f]) @ np.linalg.inv(_to_matrix(*poses[a][f]))
                 for f in both]
        if not cands:
            raise CalibrationError(f"cameras {a} and {b} have no frame in which both have a "
                                   "board pose; hold the board where both see more of it")
        T_c_ref[b] = robust_mean_transform(cands) @ T_c_ref[a]
    return np.array([_to_vector(T_c_ref[n]) for n in names])


def initial_board_poses(names: Sequence[str], frames: Sequence[int], extrinsics: np.ndarray,
                        poses: Mapping[str, Mapping[int, tuple[np.ndarray, np.ndarray]]],
                        points: Mapping[str, Mapping[int, int]]) -> np.ndarray:
    """(F, 6) T_ref_board of each of ``frames``: the pose of the camera with the most points
    in that frame, moved into the reference camera's frame.

    Args:
        frames: rig frame indices; each must have a pose in at least one camera.
        extrinsics: (N, 6) T_c_ref.
        poses: per camera, frame index -> T_cam_board.
        points: per camera, frame index -> number of points it measures there.
    """
    out = np.zeros((len(frames), 6))
    for i, f in enumerate(frames):
        have = [k for k, n in enumerate(names) if f in poses[n]]
        k = max(have, key=lambda j: points[names[j]].get(f, 0))
        T_ref_c = np.linalg.inv(_to_matrix(extrinsics[k, :3], extrinsics[k, 3:]))
        out[i] = _to_vector(T_ref_c @ _to_matrix(*poses[names[k]][f]))
    return out
