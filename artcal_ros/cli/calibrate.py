"""``artcal calibrate``: calibrate a camera from images or a rosbag2 recording.

::

    artcal calibrate IMAGE... --params P [--set KEY=VALUE]... --output camera.yaml [--report DIR]
    artcal calibrate --bag BAG [--topic T] --params P --output camera.yaml [--report DIR]
    artcal calibrate IMAGE... --size 8x6 --square 0.108 --output camera.yaml   # a chessboard
    artcal calibrate IMAGE... --target april_6x6.yaml --output camera.yaml    # Kalibr's target
    artcal calibrate IMAGE... --params P --accept-weak --report DIR   # a weak set, solved anyway
    artcal calibrate --camera left='l/*.png' --camera right='r/*.png' --params P --output-dir D
    artcal calibrate --bag BAG --camera left=/left/image_raw --camera right=/right/image_raw \
        --params P --output-dir D [--report DIR]       # a rig: cli/calibrate_rig.py

From a bag every frame of the topic is detected (``--max-frames N`` or ``--time-budget S``
bound it), on one process per CPU (``--jobs N``, :mod:`artcal_ros.core.detect.frames`), and
the views are chosen from all of them.

The solve options are the parameters file's (``camera_model``, ``points``, ``max_views``,
``calibrate.*``), as for the calibrator node; the detection, solve, write and summary are
the solve run the node uses too (:mod:`artcal_ros.core.calibrate.solve_run`).

The output starts with the verdict (good / usable / poor and why,
:mod:`artcal_ros.core.calibrate.verdict`); a board found in under half of the images is said
first, with what a few of the other images show instead
(:mod:`artcal_ros.core.calibrate.diagnosis`). ``--report DIR`` is written for a refused set
too (:mod:`artcal_ros.cli.calibrate_report`).

Exit status: 0 written; 1 the views cannot support a calibration (the reason is
printed and no file is written, an existing one is left as it was); 2 bad usage or
input.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.cli.bag_images import frames_affordable, message_image
from artcal_ros.cli.calibrate_report import (
    FrameSample,
    arrange_summary,
    write_refused_report,
    write_report,
)
from artcal_ros.cli.calibrate_rig import add_rig_arguments, run_rig
from artcal_ros.cli.common import (
    add_board_arguments,
    add_params_arguments,
    board_overrides,
    check_writable,
    params_from_args,
)
from artcal_ros.cli.progress import Progress
from artcal_ros.cli.skipped import SkippedFrames, expand_image_paths, read_image_file
from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.board_check import check_board
from artcal_ros.core.calibrate.diagnosis import BoardSearch
from artcal_ros.core.calibrate.solve_run import solve_summary, solve_views
from artcal_ros.core.detect import Detector, DetectorConfig
from artcal_ros.core.detect.frames import detect_frames
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import BagError, CalibrationError, ImageFormatError, ParameterError

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
DEFAULT_TOPIC = "/camera/image_raw"
RIG_MAX_FRAMES, RIG_BUDGET_S = 400, 40.0  # a rig's default --max-frames and --time-budget


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The verb's arguments."""
    parser.add_argument("images", nargs="*", metavar="IMAGE", help="image files (PNG, JPEG, ...)")
    parser.add_argument("--bag", metavar="BAG", help="rosbag2 directory or .mcap file to read")
    parser.add_argument("--topic", metavar="T",
                        help="image topic in the bag (default: its only Image/CompressedImage "
                             f"topic, else {DEFAULT_TOPIC})")
    add_params_arguments(parser)
    parser.add_argument("--output", metavar="camera.yaml",
                        help="calibration file to write (default: the output_file parameter, "
                             "else ~/.ros/camera_info/<camera_name>.yaml)")
    parser.add_argument("--report", metavar="DIR",
                        help="also write report.pdf (its first page says whether the result "
                             "is good and what to do if not), each page as PNG, summary.json "
                             "and detections.json into DIR (a refused set too: the reason, "
                             "the detections per image and the coverage of the points found)")
    parser.add_argument("--accept-weak", action="store_true",
                        help="solve a set the view checks refuse (fewer than 3 usable views, "
                             "all at one tilt) when a solve is possible at all; the first "
                             "line of the output then states how uncertain the result is")
    parser.add_argument("--max-views", type=int, default=None, metavar="N",
                        help="solve from at most N diverse views (default: the max_views "
                             "parameter, 40)")
    parser.add_argument("--max-frames", type=int, default=None, metavar="N",
                        help="from a bag, detect markers in at most N frames spread evenly "
                             "over the recording (default 0 = every frame; a rig: 400)")
    parser.add_argument("--time-budget", type=float, default=None, metavar="S",
                        help="from a bag, space the frames so that reading and detecting "
                             "take about S seconds (default 0 = no limit; a rig: 40)")
    parser.add_argument("--jobs", type=int, default=0, metavar="N",
                        help="processes that detect one camera's frames (default 0 = one "
                             "per CPU)")
    add_board_arguments(parser)
    parser.add_argument("--k3", action="store_true",
                        help="deprecated: the same as --set calibrate.k_coefficients=3 "
                             "(plumb_bob: also estimate k3, for strong wide-angle distortion)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_rig_arguments(parser)


def _bag_topic(topics: dict[str, str], wanted: str | None, bag: str) -> str:
    if wanted is not None:
        if wanted not in topics:
            listed = ", ".join(f"{t} ({kind or 'no type'})" for t, kind in sorted(topics.items()))
            raise ParameterError(f"--topic {wanted}: not in {bag} (topics: {listed or 'none'})")
        if topics[wanted] not in IMAGE_TYPES:
            raise ParameterError(f"--topic {wanted}: is {topics[wanted]}, not an image topic")
        return wanted
    images = sorted(t for t, kind in topics.items() if kind in IMAGE_TYPES)
    if len(images) == 1:
        return images[0]
    if DEFAULT_TOPIC in images:
        return DEFAULT_TOPIC
    if not images:
        raise ParameterError(f"{bag} holds no sensor_msgs Image or CompressedImage topic")
    raise ParameterError(f"{bag} holds several image topics ({', '.join(images)}); "
                         "choose one with --topic")


def _bag_frames(bag: str, topic: str | None, max_frames: int, budget_s: float,
                bar: Progress[Any], skipped: SkippedFrames,
                warn: Callable[[str], None]) -> Iterator[tuple[str, np.ndarray]]:
    """Frames of the bag's image topic: every one, or spread evenly over the recording.

    At most ``max_frames`` (0: no limit) are decoded; with a time budget (0: none) the
    spacing adapts as detection goes, so reading and detecting stay within about
    ``budget_s`` seconds whatever the detector's speed. ``bar`` is given the frames to
    come as its total (and counts the skipped ones). Messages that do not decode or
    convert are skipped and counted in ``skipped``; a recording broken part-way gives its
    frames before the break, and ``warn`` is told where it broke.
    """
    from artcal_ros.bag import BagReader

    start = time.monotonic()
    with BagReader(bag) as reader:
        name = _bag_topic(reader.topics, topic, bag)
        total = reader.message_count if len(reader.topics) == 1 else None
        if total is None:  # count this topic's messages (cheap: no decoding)
            total = sum(1 for _ in reader.messages(name, on_damage="stop"))
        cap = total if max_frames <= 0 else min(max_frames, total)
        bar.total, bar.label = cap, f"detect {name}"
        taken = 0
        next_index = 0.0
        for k, m in enumerate(reader.messages(name, on_damage="stop")):
            if k < next_index:
                continue
            try:
                image = message_image(m)
            except (BagError, ImageFormatError) as e:
                skipped.add(e)
                bar.update()
                next_index = k + 1  # the next message stands in for this one
                continue
            yield f"{name}#{k}@{m.log_time_ns}", image
            taken += 1
            # Frames still affordable, spread over the messages still to come.
            left = frames_affordable(cap - taken, taken, time.monotonic() - start, budget_s)
            if left <= 0:
                break
            next_index = k + max(1.0, (total - k - 1) / left)
        for text in dict.fromkeys(reader.warnings):  # each once, in order
            warn(text)


def _file_frames(paths: list[str], bar: Progress[Any],
                 skipped: SkippedFrames) -> Iterator[tuple[str, np.ndarray]]:
    bar.total = len(paths)
    for path in paths:
        try:
            image = read_image_file(path)
        except ImageFormatError as e:
            skipped.add(e)
            bar.update()
            continue
        yield path, image


def _detect_all(frames: Iterator[tuple[str, np.ndarray]], detector: Detector, jobs: int,
                bar: Progress[Any]) -> tuple[list[Detections], tuple[int, int]]:
    """Every frame detected (on ``jobs`` processes, 0: one per CPU), and the image size."""
    dets: list[Detections] = []
    for d in detect_frames(frames, detector, workers=jobs):
        dets.append(d)
        bar.update()
    bar.close()
    if not dets:
        raise ParameterError("no images: give image files or --bag BAG")
    return dets, dets[0].image_size


def _one_size(frames: Iterator[tuple[str, np.ndarray]],
              skipped: SkippedFrames) -> Iterator[tuple[str, np.ndarray]]:
    """The frames of the first frame's size; the others skipped (one camera at a time)."""
    size: tuple[int, ...] | None = None
    for source, image in frames:
        if size is None:
            size = image.shape[:2]
        if image.shape[:2] != size:
            skipped.add(f"{image.shape[1]}x{image.shape[0]} image, not the first frame's "
                        f"{size[1]}x{size[0]}")
            continue
        yield source, image


def _k3_alias(args: argparse.Namespace, params: dict[str, Any]) -> dict[str, Any]:
    """The parameters with the deprecated ``--k3`` applied (calibrate.k_coefficients = 3)."""
    if not args.k3:
        return params
    print("artcal calibrate: --k3 is deprecated; use --set calibrate.k_coefficients=3",
          file=sys.stderr)
    if params["camera_model"] != "plumb_bob":
        raise ParameterError(f"--k3 is for camera_model plumb_bob, not {params['camera_model']}; "
                             "set calibrate.k_coefficients instead")
    if int(params["calibrate.k_coefficients"]) not in (0, 3):
        raise ParameterError(f"--k3 contradicts calibrate.k_coefficients="
                             f"{params['calibrate.k_coefficients']}; give one of them")
    return {**params, "calibrate.k_coefficients": 3}


def run(args: argparse.Namespace) -> int:
    """Run the verb; see the module docstring for the exit status."""
    params = _k3_alias(args, params_from_args(args, board_overrides(args)))
    board = Board.from_params(params)
    if args.camera or args.output_dir or args.intrinsics:
        # a rig's frames are detected one by one: a budget by default
        args.max_frames = RIG_MAX_FRAMES if args.max_frames is None else args.max_frames
        args.time_budget = RIG_BUDGET_S if args.time_budget is None else args.time_budget
        return run_rig(args, params, board)
    if bool(args.images) == bool(args.bag):
        raise ParameterError("give either image files or --bag BAG (not both, not neither)")
    if args.topic and not args.bag:
        raise ParameterError("--topic needs --bag")
    if args.jobs < 0:
        raise ParameterError(f"--jobs {args.jobs}: must be 0 (one per CPU) or more")
    if args.max_views is not None and args.max_views < 3:
        raise ParameterError(f"--max-views {args.max_views}: must be at least 3")
    for flag, path in (("--output", args.output), ("--report", args.report)):
        if path:
            check_writable(flag, path)

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"calibrate: {msg}", file=sys.stderr)

    def warn(msg: str) -> None:
        print(f"artcal calibrate: warning: {msg}", file=sys.stderr)

    skipped = SkippedFrames()
    bar: Progress[Any] = Progress(label="detect", enabled=not args.quiet)
    frames = (_bag_frames(args.bag, args.topic, args.max_frames or 0, args.time_budget or 0.0,
                          bar, skipped, warn)
              if args.bag
              else _file_frames(expand_image_paths(list(args.images)), bar, skipped))
    start = time.monotonic()
    detector = Detector(board, DetectorConfig.from_params(params))
    sample = FrameSample()  # a few frames, to search for what else is in view
    try:
        dets, size = _detect_all(sample.wrap(_one_size(frames, skipped)), detector, args.jobs,
                                 bar)
    except ParameterError:
        if not skipped.count:
            raise
        raise ImageFormatError(f"no usable frame: {skipped.summary()}") from None
    if skipped.count:
        warn(skipped.summary())
    # searched only when the board is missing from most images (the search costs only then)
    search = BoardSearch.of(dets, board, points=str(params["points"]), images=sample.images())
    sample.kept.clear()
    tone = detector.tone
    try:
        run = solve_views(dets, board, size, params, output=args.output,
                                max_views=args.max_views, accept_weak=args.accept_weak,
                                progress=say)
    except CalibrationError as e:
        reason = f"{search.text()}; {e}" if search.partial else str(e)
        if args.report:
            write_refused_report(Path(args.report), reason, dets, board, params, size,
                                 {"tone_curve": tone.as_dict(),
                                  "board_check": check_board([], board).as_dict(),
                                  "board_found": search.as_dict()})
            reason += f" (report written to {args.report})"
        raise CalibrationError(reason) from None
    check = check_board([dets[i] for i in run.result.views_used], board,
                        run.result.camera)
    if check.warning:
        warn(f"board check: {check.warning}")
    if args.report:
        say(f"writing the report into {args.report} (report.pdf and its pages as PNG)")
        write_report(Path(args.report), run.result, dets, board,
                     {"tone_curve": tone.as_dict(), "board_check": check.as_dict(),
                      "board_found": search.as_dict()})
    # The run's time is the solve's; the user waited for the detection too.
    text = solve_summary(replace(run, seconds=time.monotonic() - start), long=True)
    print(arrange_summary(text, search, run.result))
    if board.n_markers:  # the tone curve is estimated from marker edges, checked on markers
        print(f"tone curve: {tone.text()}")
    if board.board_type == "marker_grid":  # the only board the print check measures
        print(f"board check: {check.text()}")
    if skipped.count:
        print(skipped.summary())
    return 0

