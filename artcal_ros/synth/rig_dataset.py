"""Render a rig's synchronised frames to disk: a folder per camera, or one bag, with the truth.

The library half of ``artcal synth --rig``::

    from artcal_ros.synth.rig_dataset import write_rig_dataset
    truth = write_rig_dataset(board, Rig.preset("stereo", Camera.preset("webcam")), "/tmp/st",
                              frames=16)

Without ``bag``: DIR/<camera>/frame_0000.png ... (the same file names in every camera's
folder, one name one instant), DIR/<camera>/truth.json (that camera alone, the
single-camera truth) and DIR/truth.json (the rig's, :mod:`artcal_ros.synth.rig_truth`).
With ``bag``: DIR is one rosbag2 directory with a topic per camera, ``/<camera>/image_raw``
(header frame_id the camera's name), all stamped with the frame's time, each camera's
stamp moved by up to ``jitter_ms`` when asked; DIR/truth.json beside the recording.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.errors import ArtcalError, ParameterError
from artcal_ros.synth.backdrop import Backdrop
from artcal_ros.synth.dataset import (
    BAG_START_NS,
    IMAGE_TYPE,
    check_arguments,
    frame_photometry,
    motion_blur_from_poses,
)
from artcal_ros.synth.rig import Rig, rig_poses
from artcal_ros.synth.rig_truth import write_rig_truth
from artcal_ros.synth.truth import write_truth
from artcal_ros.synth.view import RenderedView, render_view


def rig_topic(name: str) -> str:
    """The bag topic of camera ``name``: ``/<name>/image_raw``."""
    return f"/{name}/image_raw"


def write_rig_dataset(board: Board, rig: Rig, out: str | Path, *, frames: int, seed: int = 0,
                      photometry: str = "clean", encoding: str = "mono8",
                      partial_fraction: float = 0.3, motion: str = "random",
                      bag: bool = False, rate_hz: float = 10.0, shutter_s: float = 0.0,
                      jitter_ms: float = 0.0, overwrite: bool = False,
                      progress: Callable[[], None] | None = None) -> Path:
    """Render ``frames`` synchronised frames of every camera of ``rig`` and write them.

    Deterministic: the same arguments give the same images, stamps and truth.

    Args:
        board: the board to render.
        rig: the cameras and their places (:class:`~artcal_ros.synth.rig.Rig`).
        out: the output directory (a folder per camera + truth.json), or the bag directory.
        frames: number of frames, >= 1.
        seed: random seed of the poses, the photometry, the backdrop and the jitter.
        photometry, encoding, partial_fraction, motion, rate_hz, shutter_s, overwrite: as
            for :func:`artcal_ros.synth.dataset.write_dataset` (one photometry per frame,
            shared by the cameras: the same light falls on the board).
        bag: write one rosbag2 MCAP directory with a topic per camera.
        jitter_ms: with ``bag``: each camera after the first is stamped up to this many
            milliseconds before or after the frame's time (uniform; the first camera on it),
            as unsynchronised cameras are.
        progress: called once after each frame of each camera is written.

    Returns:
        the path of the rig's ``truth.json``.

    Raises:
        ParameterError: a bad argument, named by its ``artcal synth`` option.
        ArtcalError: the output cannot be written.
    """
    check_arguments(frames, photometry, encoding, motion, rate_hz, shutter_s)
    if not 0 <= jitter_ms < 500 / rate_hz:
        raise ParameterError(f"--jitter-ms: {jitter_ms} must be >= 0 and under half the frame "
                             f"interval ({500 / rate_hz:g} ms)")
    out = Path(out)
    rng = np.random.default_rng(seed)
    first_poses = rig_poses(board, rig, frames, rng, partial_fraction=partial_fraction,
                            motion=motion)
    cam_poses = {n: [rig.camera_pose(n, p) for p in first_poses] for n in rig.names}
    phot_rng = np.random.default_rng([seed, 1])
    jitter_rng = np.random.default_rng([seed, 3])
    wall = Backdrop.random(board, np.random.default_rng([seed, 2]))

    def render(i: int) -> dict[str, RenderedView]:
        phot = frame_photometry(photometry, phot_rng)
        views = {}
        for k, (name, cam) in enumerate(zip(rig.names, rig.cameras, strict=True)):
            p = phot
            if motion == "smooth" and shutter_s > 0:
                length, angle = motion_blur_from_poses(board, cam, cam_poses[name], i,
                                                       shutter_s * rate_hz)
                p = phot.with_(motion_px=length, motion_angle_deg=angle)
            views[name] = render_view(board, cam, *cam_poses[name][i],
                                      rng=np.random.default_rng([seed, 4, i, k]),
                                      encoding=encoding, photometry=p, backdrop=wall)
        return views

    records: list[dict[str, Any]] = []
    per_camera: dict[str, list[dict[str, Any]]] = {n: [] for n in rig.names}
    settings: dict[str, Any] = {"name": photometry, "encoding": encoding, "motion": motion,
                                "partial_fraction": partial_fraction, "shutter_s": shutter_s}
    if bag:
        # imported here: the bag writer pulls in mcap, which PNG output does not need
        from artcal_ros.bag import BagWriter
        from artcal_ros.core.images import numpy_to_image
        with BagWriter(out, storage="directory", overwrite=overwrite) as writer:
            for i in range(frames):
                views = render(i)
                stamp = BAG_START_NS + round(i * 1e9 / rate_hz)
                stamps = {n: stamp + (0 if k == 0 else round(
                    jitter_rng.uniform(-jitter_ms, jitter_ms) * 1e6))
                    for k, n in enumerate(rig.names)}
                for name in sorted(rig.names, key=lambda n: stamps[n]):
                    writer.write(rig_topic(name), IMAGE_TYPE, stamps[name],
                                 numpy_to_image(views[name].image, encoding, stamps[name], name))
                    if progress:
                        progress()
                records.append(_frame(first_poses[i], {
                    n: views[n].truth_record(stamp_ns=stamps[n]) for n in rig.names},
                    stamp_ns=stamp))
        settings.update(rate_hz=rate_hz, jitter_ms=jitter_ms)
    else:
        for name in rig.names:
            try:
                (out / name).mkdir(parents=True, exist_ok=True)
            except OSError as e:
                raise ArtcalError(f"--out: cannot create directory {out / name}: "
                                  f"{e.strerror}") from e
        for i in range(frames):
            views = render(i)
            file = f"frame_{i:04d}.png"
            for name in rig.names:
                if not cv2.imwrite(str(out / name / file), views[name].image):
                    raise ArtcalError(f"cannot write {out / name / file}")
                per_camera[name].append(views[name].truth_record(file=file))
                if progress:
                    progress()
            records.append(_frame(first_poses[i], {n: per_camera[n][-1] for n in rig.names},
                                  file=file))
        for name, cam in zip(rig.names, rig.cameras, strict=True):
            write_truth(out / name / "truth.json", cam, board, per_camera[name], seed=seed,
                        photometry={**settings, "rig": rig.name, "camera": name})
    truth = out / "truth.json"
    write_rig_truth(truth, rig, board, records, seed=seed, photometry=settings,
                    topics={n: rig_topic(n) for n in rig.names} if bag else None)
    return truth


def _frame(first_board: tuple[np.ndarray, np.ndarray], cameras: dict[str, Any], *,
           file: str | None = None, stamp_ns: int | None = None) -> dict[str, Any]:
    rec: dict[str, Any] = {"file": file} if file is not None else {"stamp_ns": int(stamp_ns or 0)}
    rec["rvec"] = [float(v) for v in np.ravel(first_board[0])]
    rec["tvec"] = [float(v) for v in np.ravel(first_board[1])]
    rec["cameras"] = cameras
    return rec
