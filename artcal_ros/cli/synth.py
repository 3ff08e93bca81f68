"""``artcal synth``: render synthetic frames of the board with exact ground truth.

    artcal synth --params config/calibrator.yaml --camera webcam --frames 20 --out /tmp/frames
    artcal synth --camera hd --frames 60 --out /tmp/run1 --bag --motion smooth --rate 10
    artcal synth --camera fisheye --frames 5 --out /tmp/f --photometry harsh --encoding bgr8
    artcal synth --camera webcam --frames 16 --out /tmp/st --rig stereo       # DIR/left, DIR/right
    artcal synth --rig stereo --frames 60 --out /tmp/stbag --bag --rate 15 --jitter-ms 5

Without ``--bag``: DIR/frame_0000.png ... and DIR/truth.json. With ``--bag``: DIR is a
rosbag2 directory (metadata.yaml + .mcap) of sensor_msgs/Image on ``--topic``, with
DIR/truth.json beside the recording (frames keyed by their stamp). The truth format
is described in :mod:`artcal_ros.synth.truth`. With ``--rig stereo|trio``: synchronised
cameras of known extrinsics (:mod:`artcal_ros.synth.rig`), DIR/<camera>/ holding each
camera's frames under the same file names, or one bag with a topic ``/<camera>/image_raw``
per camera; DIR/truth.json the truth of all (:mod:`artcal_ros.synth.rig_truth`). This module
only parses the arguments; the rendering and writing is
:func:`artcal_ros.synth.dataset.write_dataset` (:func:`artcal_ros.synth.rig_dataset.
write_rig_dataset` for a rig).
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import time
from pathlib import Path

from artcal_ros.cli.common import add_params_arguments, params_from_args
from artcal_ros.cli.progress import Progress
from artcal_ros.core.board import Board
from artcal_ros.core.errors import ParameterError
from artcal_ros.synth import ENCODINGS, PRESETS, Camera
from artcal_ros.synth.dataset import PHOTOMETRIES, write_dataset
from artcal_ros.synth.rig import RIGS, Rig
from artcal_ros.synth.rig_dataset import rig_topic, write_rig_dataset


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
    parser.add_argument("--topic", default=None,
                        help="image topic in the bag (default /camera/image_raw; a rig's "
                             "are /<camera>/image_raw)")
    parser.add_argument("--rig", choices=RIGS, default=None,
                        help="synchronised cameras of known extrinsics, copies of --camera: "
                             "stereo (left, right: 12 cm apart) or trio (cam0 cam1 cam2 fanned "
                             "out, the outer two sharing no view); DIR/<camera>/ holds each "
                             "camera's frames, DIR/truth.json the truth of all")
    parser.add_argument("--jitter-ms", type=float, default=0.0, metavar="MS",
                        help="with --rig and --bag: stamp each camera after the first up to "
                             "MS milliseconds off the frame's time (default 0: identical)")
    parser.add_argument("--overwrite", action="store_true",
                        help="with --bag: replace an existing bag at DIR")


def run(args: argparse.Namespace) -> int:
    """Render, write, and print a one-line summary."""
    _keep_freed_memory()
    board = Board.from_params(params_from_args(args))
    cam = camera_from_arg(args.camera)
    if args.rig:
        return _run_rig(args, board, cam)
    if args.jitter_ms:
        raise ParameterError("--jitter-ms is for a rig's bag (--rig ... --bag)")
    bar: Progress[None] = Progress(total=args.frames, label="synth")
    start = time.monotonic()
    truth = write_dataset(board, cam, args.out, frames=args.frames, seed=args.seed,
                          photometry=args.photometry, encoding=args.encoding,
                          partial_fraction=args.partial_fraction, motion=args.motion,
                          bag=args.bag, rate_hz=args.rate,
                          topic=args.topic or "/camera/image_raw",
                          shutter_s=args.shutter, overwrite=args.overwrite,
                          progress=bar.update)
    bar.close()
    seconds = time.monotonic() - start
    kind = "bag" if args.bag else "PNGs"
    print(f"wrote {args.frames} frames ({cam.width}x{cam.height} {Path(args.camera).name}, "
          f"{args.encoding}) as {kind} in {args.out} and truth in {truth} "
          f"({seconds:.1f} s, {seconds / args.frames:.2f} s/frame)")
    return 0


def _run_rig(args: argparse.Namespace, board: Board, cam: Camera) -> int:
    """``--rig``: render every camera of the rig, write, and print a one-line summary."""
    if args.topic is not None:
        raise ParameterError(f"--topic {args.topic}: a rig's topics are /<camera>/image_raw; "
                             "leave --topic out with --rig")
    if args.jitter_ms and not args.bag:
        raise ParameterError("--jitter-ms needs --bag (image folders have no stamps)")
    rig = Rig.preset(args.rig, cam)
    bar: Progress[None] = Progress(total=args.frames * len(rig.names), label="synth")
    start = time.monotonic()
    truth = write_rig_dataset(board, rig, args.out, frames=args.frames, seed=args.seed,
                              photometry=args.photometry, encoding=args.encoding,
                              partial_fraction=args.partial_fraction, motion=args.motion,
                              bag=args.bag, rate_hz=args.rate, shutter_s=args.shutter,
                              jitter_ms=args.jitter_ms, overwrite=args.overwrite,
                              progress=bar.update)
    bar.close()
    seconds = time.monotonic() - start
    where = (f"as one bag ({', '.join(rig_topic(n) for n in rig.names)})" if args.bag
             else f"as PNGs in {', '.join(n + '/' for n in rig.names)}")
    print(f"wrote {args.frames} frames of the {args.rig} rig ({', '.join(rig.names)}; "
          f"{cam.width}x{cam.height} {Path(args.camera).name}, {args.encoding}) {where} in "
          f"{args.out} and truth in {truth} ({seconds:.1f} s)")
    return 0
