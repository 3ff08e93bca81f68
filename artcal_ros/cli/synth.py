"""``artcal synth``: render synthetic frames of the board with exact ground truth.

    artcal synth --params config/calibrator.yaml --camera webcam --frames 20 --out /tmp/frames
    artcal synth --camera hd --frames 60 --out /tmp/run1 --bag --motion smooth --rate 10
    artcal synth --camera fisheye --frames 5 --out /tmp/f --photometry harsh --encoding bgr8

Without ``--bag``: DIR/frame_0000.png ... and DIR/truth.json. With ``--bag``: DIR is a
rosbag2 directory (metadata.yaml + .mcap) of sensor_msgs/Image on ``--topic``, with
DIR/truth.json beside the recording (frames keyed by their stamp). The truth format
is described in :mod:`artcal_ros.synth.truth`.
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from artcal_ros.cli.common import add_params_arguments, params_from_args
from artcal_ros.cli.progress import Progress
from artcal_ros.core.board import Board
from artcal_ros.core.errors import ArtcalError, ParameterError
from artcal_ros.synth import (
    ENCODINGS,
    PRESETS,
    Backdrop,
    Camera,
    Photometry,
    RenderedView,
    marker_truth,
    random_poses,
    render_view,
    smooth_poses,
    write_truth,
)

PHOTOMETRIES = ("clean", "harsh", "mixed", "exact")
# bag time of the first frame: a fixed instant, so a fixed seed gives a byte-identical bag
BAG_START_NS = 1_700_000_000_000_000_000


def camera_from_arg(text: str) -> Camera:
    """A preset name (webcam, hd, wide, fisheye) or a camera_info YAML file's camera."""
    if text in PRESETS or not text.lower().endswith((".yaml", ".yml")):
        return Camera.preset(text)
    from artcal_ros.core.camera_info import read_camera_info_yaml
    info = read_camera_info_yaml(text)
    try:
        return Camera(info.distortion_model, info.camera_matrix, info.dist_coeffs,
                      info.image_size)
    except ParameterError as e:
        raise ParameterError(f"--camera {text}: {e}") from None


def frame_photometry(name: str, rng: np.random.Generator) -> Photometry:
    """The photometry of one frame: ``clean``/``harsh``/``exact`` as named; ``mixed`` draws a
    mostly clean frame (light, exposure and noise varied) and one in five harsh."""
    if name != "mixed":
        return Photometry.by_name(name)
    if rng.random() < 0.2:
        return Photometry.harsh().with_(defocus_px=float(rng.uniform(0.5, 1.5)),
                                        motion_px=float(rng.uniform(0.0, 3.0)))
    return Photometry.clean().with_(gradient=float(rng.uniform(0.0, 0.3)),
                                    exposure=float(rng.uniform(0.8, 1.15)),
                                    full_well=float(rng.uniform(4000, 12000)),
                                    defocus_px=float(rng.uniform(0.0, 0.6)))


def motion_blur_from_poses(board: Board, cam: Camera, poses: list[tuple[np.ndarray,
                                                                        np.ndarray]],
                           index: int, open_fraction: float) -> tuple[float, float]:
    """Blur (length px, angle deg) of frame ``index`` of a sequence: how far the markers'
    images move while the shutter is open (``open_fraction`` of the frame interval), from
    the neighbouring frames (central difference)."""
    lo, hi = max(index - 1, 0), min(index + 1, len(poses) - 1)
    if hi == lo:
        return 0.0, 0.0
    _, a, inside_a, _ = marker_truth(board, cam, *poses[lo])
    _, b, inside_b, _ = marker_truth(board, cam, *poses[hi])
    both = inside_a & inside_b
    if not both.any():
        return 0.0, 0.0
    per_frame = np.median(b[both] - a[both], axis=0) / (hi - lo)
    dx, dy = per_frame * open_fraction
    return float(min(np.hypot(dx, dy), 100.0)), float(np.degrees(np.arctan2(dy, dx)))


def write_dataset(board: Board, cam: Camera, out: str | Path, *, frames: int, seed: int = 0,
                  photometry: str = "clean", encoding: str = "mono8",
                  partial_fraction: float = 0.3, motion: str = "random", bag: bool = False,
                  rate_hz: float = 10.0, topic: str = "/camera/image_raw",
                  shutter_s: float = 0.0, overwrite: bool = False,
                  progress: Callable[[], None] | None = None) -> Path:
    """Render ``frames`` views and write them (PNGs or a bag) with ``truth.json``.

    Deterministic: the same arguments give the same images and truth. With
    ``motion="smooth"`` and ``shutter_s`` > 0 each frame is blurred by the camera's own
    motion during that exposure time (at ``rate_hz`` frames per second).

    Returns:
        the path of the written ``truth.json``.
    """
    if photometry not in PHOTOMETRIES:
        raise ParameterError(f"--photometry: {photometry!r} is not one of "
                             f"{', '.join(PHOTOMETRIES)}")
    if encoding not in ENCODINGS:
        raise ParameterError(f"--encoding: {encoding!r} is not one of {', '.join(ENCODINGS)}")
    if frames < 1:
        raise ParameterError(f"--frames: {frames} must be >= 1")
    if not rate_hz > 0:
        raise ParameterError(f"--rate: {rate_hz} must be > 0 (frames per second)")
    if motion not in ("random", "smooth"):
        raise ParameterError(f"--motion: {motion!r} is not one of random, smooth")
    if not 0 <= shutter_s <= 1 / rate_hz:
        raise ParameterError(f"--shutter: {shutter_s} s must be between 0 and the frame "
                             f"interval {1 / rate_hz:g} s")
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
        from artcal_ros.bag import BagWriter
        from artcal_ros.core.images import numpy_to_image
        with BagWriter(out, storage="directory", overwrite=overwrite) as writer:
            for i in range(len(poses)):
                view = render(i)
                stamp = BAG_START_NS + round(i * 1e9 / rate_hz)
                writer.write(topic, "sensor_msgs/msg/Image", stamp,
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


def _keep_freed_memory() -> None:
    """Ask glibc to keep freed memory instead of returning it to the system.

    Rendering makes many short-lived image-sized numpy temporaries; by default each is
    mmap'ed, unmapped when freed and page-faulted in again for the next one, which costs
    about 0.5 s of system time per HD frame. Harmless where it does not apply."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        m_trim_threshold, m_top_pad, m_mmap_threshold = -1, -2, -3
        libc.mallopt(m_mmap_threshold, 1 << 30)
        libc.mallopt(m_trim_threshold, 1 << 30)
        libc.mallopt(m_top_pad, 64 << 20)
    except (OSError, AttributeError):
        pass


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``artcal synth``."""
    add_params_arguments(parser)
    parser.add_argument("--camera", default="webcam", metavar="PRESET",
                        help=f"camera preset ({', '.join(PRESETS)}; default webcam) or a "
                             "camera_info YAML file (plumb_bob, rational_polynomial or "
                             "equidistant)")
    parser.add_argument("--frames", type=int, default=20, metavar="N",
                        help="number of frames (default 20)")
    parser.add_argument("--out", required=True, metavar="DIR",
                        help="output directory (PNGs + truth.json, or the bag with --bag)")
    parser.add_argument("--bag", action="store_true",
                        help="write a rosbag2 MCAP directory of sensor_msgs/Image instead")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--photometry", default="clean", metavar="NAME",
                        help=f"light and sensor: {', '.join(PHOTOMETRIES)} (default clean)")
    parser.add_argument("--encoding", default="mono8", metavar="ENC",
                        help=f"image encoding: {', '.join(ENCODINGS)} (default mono8)")
    parser.add_argument("--partial-fraction", type=float, default=0.3, metavar="F",
                        help="share of close views where the board overfills the image "
                             "(default 0.3)")
    parser.add_argument("--motion", default="random", metavar="KIND",
                        help="random: independent views; smooth: a hand-held sweep between "
                             "random key views (default random)")
    parser.add_argument("--rate", type=float, default=10.0, metavar="HZ",
                        help="frame rate of the bag's time stamps (default 10)")
    parser.add_argument("--shutter", type=float, default=0.0, metavar="SECONDS",
                        help="with --motion smooth: exposure time; each frame is blurred by "
                             "the camera's motion while the shutter is open (default 0: off)")
    parser.add_argument("--topic", default="/camera/image_raw",
                        help="image topic in the bag (default /camera/image_raw)")
    parser.add_argument("--overwrite", action="store_true",
                        help="with --bag: replace an existing bag at DIR")


def run(args: argparse.Namespace) -> int:
    """Render, write, and print a one-line summary."""
    _keep_freed_memory()
    board = Board.from_params(params_from_args(args))
    cam = camera_from_arg(args.camera)
    bar: Progress[None] = Progress(total=args.frames, label="synth")
    start = time.monotonic()
    truth = write_dataset(board, cam, args.out, frames=args.frames, seed=args.seed,
                          photometry=args.photometry, encoding=args.encoding,
                          partial_fraction=args.partial_fraction, motion=args.motion,
                          bag=args.bag, rate_hz=args.rate, topic=args.topic,
                          shutter_s=args.shutter, overwrite=args.overwrite,
                          progress=bar.update)
    bar.close()
    seconds = time.monotonic() - start
    kind = "bag" if args.bag else "PNGs"
    print(f"wrote {args.frames} frames ({cam.width}x{cam.height} {Path(args.camera).name}, "
          f"{args.encoding}) as {kind} in {args.out} and truth in {truth} "
          f"({seconds:.1f} s, {seconds / args.frames:.2f} s/frame)")
    return 0

