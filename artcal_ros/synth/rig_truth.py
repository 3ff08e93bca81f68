"""Ground truth of a rendered rig: the rig's ``truth.json`` and its reader.

Format (the per-camera frame records are the single-camera ones of
:mod:`artcal_ros.synth.truth`)::

    {"rig": "stereo" | "trio",
     "cameras": [{"name": "left", "camera": {"model", "K", "dist", "width", "height"},
                  "topic": "/left/image_raw"}, ...],        # topic: bags only
     "extrinsics": [{"from": "left", "to": "right",          # T_to_from: p_to = R p_from + t
                     "rotation": 3x3, "translation": [3], "baseline_m": float}, ...],
     "board": {"board.type", ...}, "photometry": {...}, "seed": int | null,
     "frames": [{"file": "frame_0000.png" | "stamp_ns": int,
                 "rvec": [3], "tvec": [3],                   # T_first_board, metres
                 "cameras": {"left": {frame record}, "right": {frame record}}}]}

``extrinsics`` has one entry per camera after the first, ``from`` the first camera. In a
bag each camera's record carries its own ``stamp_ns`` (the frame's, jittered when asked).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.errors import ArtcalError
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.rig import Rig
from artcal_ros.synth.truth import TruthFrame, board_params, truth_frame, write_json_atomic


@dataclass(frozen=True)
class RigTruthFrame:
    """One synchronised frame of a rig.

    Attributes:
        file: the image file name every camera's folder holds (PNG output) or None.
        stamp_ns: the frame's time in a bag (each camera's own stamp is in its view) or None.
        rvec, tvec: (3,) T_first_board (Rodrigues vector; metres).
        views: camera name -> that camera's truth of the frame (its own T_cam_board, stamp).
    """

    file: str | None
    stamp_ns: int | None
    rvec: np.ndarray
    tvec: np.ndarray
    views: dict[str, TruthFrame]


@dataclass(frozen=True)
class RigTruth:
    """A whole rig ``truth.json``.

    Attributes:
        rig: the rig's name.
        names: the cameras' names, the first the reference of the extrinsics.
        cameras: name -> camera.
        topics: name -> image topic (bags), else empty.
        poses: name -> T_name_first as (R (3, 3), t (3,) metres).
        board, frames, photometry, seed: as in a single camera's truth.
    """

    rig: str
    names: tuple[str, ...]
    cameras: dict[str, Camera]
    topics: dict[str, str]
    poses: dict[str, tuple[np.ndarray, np.ndarray]]
    board: Board
    frames: list[RigTruthFrame]
    photometry: dict[str, Any]
    seed: int | None

    def extrinsics(self, a: str, b: str) -> tuple[np.ndarray, np.ndarray]:
        """T_b_a as (R (3, 3), t (3,) metres): a point in camera a's frame -> b's frame."""
        for name in (a, b):
            if name not in self.poses:
                raise ArtcalError(f"the rig has no camera {name!r} ({', '.join(self.names)})")
        Ra, ta = self.poses[a]
        Rb, tb = self.poses[b]
        R = Rb @ Ra.T
        return R, tb - R @ ta


def extrinsics_record(rig: Rig, a: str, b: str) -> dict[str, Any]:
    """The ``extrinsics`` entry T_b_a of ``rig``."""
    R, t = rig.extrinsics(a, b)
    return {"from": a, "to": b, "rotation": R.tolist(), "translation": t.tolist(),
            "baseline_m": float(np.linalg.norm(t))}


def write_rig_truth(path: str | Path, rig: Rig, board: Board,
                    frames: Sequence[dict[str, Any]], *, topics: dict[str, str] | None = None,
                    photometry: dict[str, Any] | None = None, seed: int | None = None) -> None:
    """Write the rig's ``truth.json`` atomically.

    Args:
        frames: ``{"file" | "stamp_ns", "rvec", "tvec", "cameras": {name: record}}`` each,
            the records from :func:`artcal_ros.synth.truth.frame_record`.
        topics: camera name -> image topic, for a bag.
    """
    cams = [{"name": n, "camera": c.to_dict(),
             **({"topic": topics[n]} if topics and n in topics else {})}
            for n, c in zip(rig.names, rig.cameras, strict=True)]
    doc = {"rig": rig.name, "cameras": cams,
           "extrinsics": [extrinsics_record(rig, rig.names[0], n) for n in rig.names[1:]],
           "board": board_params(board), "photometry": photometry or {}, "seed": seed,
           "frames": list(frames)}
    write_json_atomic(path, doc)


def load_rig_truth(path: str | Path) -> RigTruth:
    """Read a rig ``truth.json`` written by ``artcal synth --rig`` (ArtcalError if it is
    not one)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
        names = tuple(str(c["name"]) for c in doc["cameras"])
        cameras = {str(c["name"]): Camera.from_dict(c["camera"]) for c in doc["cameras"]}
        topics = {str(c["name"]): str(c["topic"]) for c in doc["cameras"] if "topic" in c}
        poses = {names[0]: (np.eye(3), np.zeros(3))}
        for e in doc["extrinsics"]:
            poses[str(e["to"])] = (np.array(e["rotation"], np.float64).reshape(3, 3),
                                   np.array(e["translation"], np.float64).reshape(3))
        frames = [RigTruthFrame(file=f.get("file"),
                                stamp_ns=int(f["stamp_ns"]) if "stamp_ns" in f else None,
                                rvec=np.array(f["rvec"], np.float64),
                                tvec=np.array(f["tvec"], np.float64),
                                views={str(n): truth_frame(r) for n, r in f["cameras"].items()})
                  for f in doc["frames"]]
        board = Board.from_params(doc["board"])
    except OSError as e:
        raise ArtcalError(f"cannot read truth file {path}: {e.strerror}") from e
    except (ValueError, KeyError, TypeError, IndexError) as e:
        raise ArtcalError(f"{path} is not a rig truth.json written by 'artcal synth --rig' "
                          f"({type(e).__name__}: {e})") from e
    return RigTruth(rig=str(doc.get("rig", "")), names=names, cameras=cameras, topics=topics,
                    poses=poses, board=board, frames=frames,
                    photometry=dict(doc.get("photometry") or {}), seed=doc.get("seed"))
