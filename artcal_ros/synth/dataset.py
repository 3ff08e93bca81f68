"""Render a whole synthetic data set to disk: PNGs or a rosbag2 recording, with its truth.

The library half of ``artcal synth`` (the command only parses its arguments and calls
:func:`write_dataset`); the benchmarks and ``bench/make_sample_bag.py`` call it directly::

    from artcal_ros.synth.dataset import write_dataset
    truth_path = write_dataset(board, Camera.preset("webcam"), "/tmp/run", frames=60,
                               motion="smooth", bag=True, rate_hz=10.0)

Without ``bag``: DIR/frame_0000.png ... and DIR/truth.json. With ``bag``: DIR is a rosbag2
directory (metadata.yaml + .mcap) of sensor_msgs/Image on ``topic``, with DIR/truth.json
beside the recording (frames keyed by their stamp). The truth format is described in
:mod:`artcal_ros.synth.truth`.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.errors import ArtcalError, ParameterError
from artcal_ros.synth.backdrop import Backdrop
from artcal_ros.synth.camera import Camera
from artcal_ros.synth.photometry import ENCODINGS, Photometry
from artcal_ros.synth.poses import marker_truth, point_truth, random_poses, smooth_poses
from artcal_ros.synth.truth import write_truth
from artcal_ros.synth.view import RenderedView, render_view

PHOTOMETRIES = ("clean", "harsh", "mixed", "exact")
MOTIONS = ("random", "smooth")
# bag time of the first frame: a fixed instant, so a fixed seed gives a byte-identical bag
BAG_START_NS = 1_700_000_000_000_000_000
IMAGE_TYPE = "sensor_msgs/msg/Image"

Pose = tuple[np.ndarray, np.ndarray]


def frame_photometry(name: str, rng: np.random.Generator) -> Photometry:
    """The photometry of one frame of a sequence.

    Args:
        name: ``clean``, ``harsh`` or ``exact`` (that photometry for every frame), or
            ``mixed``: a mostly clean frame (light, exposure and noise varied) and one in
            five harsh.
        rng: drawn from for ``mixed`` only.
    """
    if name != "mixed":
        return Photometry.by_name(name)
    if rng.random() < 0.2:
        return Photometry.harsh().with_(defocus_px=float(rng.uniform(0.5, 1.5)),
                                        motion_px=float(rng.uniform(0.0, 3.0)))
    return Photometry.clean().with_(gradient=float(rng.uniform(0.0, 0.3)),
                                    exposure=float(rng.uniform(0.8, 1.15)),
                                    full_well=float(rng.uniform(4000, 12000)),
                                    defocus_px=float(rng.uniform(0.0, 0.6)))


def motion_blur_from_poses(board: Board, cam: Camera, poses: list[Pose], index: int,
                           open_fraction: float) -> tuple[float, float]:
    """The motion blur of frame ``index`` of a sequence of views.

    How far the markers' images move while the shutter is open, from the neighbouring
    frames (central difference; the median over the markers seen in both).

    Args:
        board: the board rendered.
        cam: the camera rendering it.
        poses: the sequence's poses T_cam_board, (rvec (3,), tvec (3,) metres) each.
        index: the frame, 0 <= index < len(poses).
        open_fraction: the share of the frame interval the shutter is open (0..1).

    Returns:
        (blur length in px, capped at 100; blur direction in degrees, image x towards y).
    """
    lo, hi = max(index - 1, 0), min(index + 1, len(poses) - 1)
    if hi == lo:
        return 0.0, 0.0
    if board.has_points:
        a, inside_a, _ = point_truth(board, cam, *poses[lo])
        b, inside_b, _ = point_truth(board, cam, *poses[hi])
    else:
        _, a, inside_a, _ = marker_truth(board, cam, *poses[lo])
        _, b, inside_b, _ = marker_truth(board, cam, *poses[hi])
    both = inside_a & inside_b
    if not both.any():
        return 0.0, 0.0
    per_frame = np.median(b[both] - a[both], axis=0) / (hi - lo)
    dx, dy = per_frame * open_fraction
    return float(min(np.hypot(dx, dy), 100.0)), float(np.degrees(np.arctan2(dy, dx)))


def check_arguments(frames: int, photometry: str, encoding: str, motion: str, rate_hz: float,
                     shutter_s: float) -> None:
    """ParameterError naming the first bad argument (by its ``artcal synth`` option)."""
    if photometry not in PHOTOMETRIES:
        raise ParameterError(f"--photometry: {photometry!r} is not one of "
                             f"{', '.join(PHOTOMETRIES)}")
    if encoding not in ENCODINGS:
        raise ParameterError(f"--encoding: {encoding!r} is not one of {', '.join(ENCODINGS)}")
    if frames < 1:
        raise ParameterError(f"--frames: {frames} must be >= 1")
    if not rate_hz > 0:
        raise ParameterError(f"--rate: {rate_hz} must be > 0 (frames per second)")
    if motion not in MOTIONS:
        raise ParameterError(f"--motion: {motion!r} is not one of {', '.join(MOTIONS)}")
    if not 0 <= shutter_s <= 1 / rate_hz:
        raise ParameterError(f"--shutter: {shutter_s} s must be between 0 and the frame "
                             f"interval {1 / rate_hz:g} s")


def write_dataset(board: Board, cam: Camera, out: str | Path, *, frames: int, seed: int = 0,
                  photometry: str = "clean", encoding: str = "mono8",
                  partial_fraction: float = 0.3, motion: str = "random", bag: bool = False,
                  rate_hz: float = 10.0, topic: str = "/camera/image_raw",
                  shutter_s: float = 0.0, overwrite: bool = False,
                  progress: Callable[[], None] | None = None) -> Path:
    """Render ``frames`` views and write them (PNGs or a bag) with ``truth.json``.

    Deterministic: the same arguments give the same images and truth (and, for a bag, the
    same bytes: time stamps start at :data:`BAG_START_NS`).

    Args:
        board: the board to render.
        cam: the camera that sees it.
        out: the output directory (PNGs + truth.json), or the bag directory with ``bag``.
        frames: number of views, >= 1.
        seed: random seed of the poses, the photometry and the backdrop.
        photometry: one of :data:`PHOTOMETRIES` (see :func:`frame_photometry`).
        encoding: image encoding, one of :data:`artcal_ros.synth.photometry.ENCODINGS`.
        partial_fraction: share of close views where the board overfills the image (0..1).
        motion: ``random`` (independent views) or ``smooth`` (a hand-held sweep).
        bag: write a rosbag2 MCAP directory of sensor_msgs/Image instead of PNGs.
        rate_hz: frame rate, frames per second: the bag's time stamps, and the frame
            interval the shutter time is a share of.
        topic: the image topic in the bag.
        shutter_s: with ``motion="smooth"``: exposure time in seconds (0 .. 1 / rate_hz);
            each frame is blurred by the camera's motion while the shutter is open (0: off).
        overwrite: with ``bag``: replace an existing bag at ``out`` (else an error).
        progress: called once after each frame is written (e.g. a progress bar's update).

    Returns:
        the path of the written ``truth.json``.

    Raises:
        ParameterError: a bad argument, named by its ``artcal synth`` option.
        ArtcalError: the output cannot be written.
    """
    check_arguments(frames, photometry, encoding, motion, rate_hz, shutter_s)
    out = Path(out)
    rng = np.random.default_rng(seed)
    make = smooth_poses if motion == "smooth" else random_poses
    poses = make(board, cam, frames, rng, partial_fraction=partial_fraction)
    records = []
    phot_rng = np.random.default_rng([seed, 1])
    # one room for the whole sequence: the background moves with the camera, as it should
    wall = Backdrop.random(board, np.random.default_rng([seed, 2]))

    def render(i: int) -> RenderedView:
        phot = frame_photometry(photometry, phot_rng)
        if motion == "smooth" and shutter_s > 0:
            length, angle = motion_blur_from_poses(board, cam, poses, i, shutter_s * rate_hz)
            phot = phot.with_(motion_px=length, motion_angle_deg=angle)
        return render_view(board, cam, *poses[i], rng=rng, encoding=encoding, photometry=phot,
                           backdrop=wall)

    if bag:
        # imported here: the bag writer pulls in mcap, which PNG output does not need
        from artcal_ros.bag import BagWriter
        from artcal_ros.core.images import numpy_to_image
        with BagWriter(out, storage="directory", overwrite=overwrite) as writer:
            for i in range(len(poses)):
                view = render(i)
                stamp = BAG_START_NS + round(i * 1e9 / rate_hz)
                writer.write(topic, IMAGE_TYPE, stamp,
                             numpy_to_image(view.image, encoding, stamp, "camera"))
                records.append(view.truth_record(stamp_ns=stamp))
                if progress:
                    progress()
    else:
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ArtcalError(f"--out: cannot create directory {out}: {e.strerror}") from e
        for i in range(len(poses)):
            view = render(i)
            name = f"frame_{i:04d}.png"
            if not cv2.imwrite(str(out / name), view.image):
                raise ArtcalError(f"cannot write {out / name}")
            records.append(view.truth_record(file=name))
            if progress:
                progress()
    truth = out / "truth.json"
    write_truth(truth, cam, board, records, seed=seed,
                photometry={"name": photometry, "encoding": encoding, "motion": motion,
                            "partial_fraction": partial_fraction, "shutter_s": shutter_s,
                            **({"rate_hz": rate_hz, "topic": topic} if bag else {})})
    return truth
