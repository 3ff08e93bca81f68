"""``artcal calibrate --camera NAME=...``: calibrate a rig of two or more cameras together.

::

    artcal calibrate --camera left='st/left/*.png' --camera right='st/right/*.png' \\
        --params P --output-dir calib [--report DIR]
    artcal calibrate --bag BAG --camera left=/stereo/left/image_raw \\
        --camera right=/stereo/right/image_raw --params P --output-dir calib
    artcal calibrate --camera left=... --camera right=... --set calibrate.fix_intrinsics=true \\
        --intrinsics left=left.yaml --intrinsics right=right.yaml --output-dir calib

Image files are paired by their sorted order (the same count per camera, else exit 2
naming both counts); bag messages by header stamp within the ``sync_tolerance`` parameter.
The solve is :func:`~artcal_ros.core.calibrate.rig.calibrate_rig` with the parameters'
``camera_model``, ``points`` and ``calibrate.*`` options; ``calibrate.fix_intrinsics``
keeps the intrinsics of the YAMLs given with ``--intrinsics`` and solves the extrinsics.

Writes ``DIR/<name>.yaml`` per camera (camera_calibration_parsers YAML; a pair with the
rectification R and P of camera_calibration's convention) and ``DIR/camchain.yaml``
(Kalibr's, :mod:`artcal_ros.core.camchain`); ``--report DIR``: ``summary.json`` (the rig's
``extrinsics``, ``rectified_epipolar_rms_px`` and ``cameras`` with each camera's
single-camera fields), ``report.pdf`` with a page per rectified pair (also
``pair_<a>_<b>.png``) and each camera's pages (also PNGs in ``DIR/<name>/``). Exit status:
0 written; 1 no calibration (the reason, e.g. a camera that shares no frame with the others);
2 bad usage or input.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.cli.common import check_writable
from artcal_ros.cli.rig_frames import RigFrames, bag_frames, folder_frames
from artcal_ros.cli.skipped import SkippedFrames
from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.board_check import check_board
from artcal_ros.core.calibrate.rig_files import rig_solve_kwargs, write_rig_files
from artcal_ros.core.calibrate.rig_result import RigResult
from artcal_ros.core.errors import ArtcalError, CalibrationError, ParameterError
from artcal_ros.core.params import SPECS


def add_rig_arguments(parser: argparse.ArgumentParser) -> None:
    """The rig options of ``artcal calibrate``."""
    group = parser.add_argument_group(
        "a rig: two or more cameras solved together (docs/conventions.md: extrinsics)")
    group.add_argument("--camera", action="append", default=[], metavar="NAME=GLOB|TOPIC",
                       help="a camera of the rig and its images: a quoted pattern of image "
                            "files (left='st/left/*.png'; paired with the other cameras' by "
                            "sorted order) or, with --bag, its image topic (paired by stamp "
                            "within sync_tolerance); repeat for each camera, the first is "
                            "the reference")
    group.add_argument("--output-dir", metavar="DIR",
                       help="with --camera: write DIR/<name>.yaml per camera (a pair with "
                            "its stereo rectification R and P) and DIR/camchain.yaml "
                            "(Kalibr's)")
    group.add_argument("--intrinsics", action="append", default=[], metavar="NAME=YAML",
                       help="with --set calibrate.fix_intrinsics=true: camera NAME's "
                            "camera_info YAML, whose intrinsics are kept (give every camera's); "
                            "only the extrinsics are solved")


def _named(values: list[str], flag: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for text in values:
        name, sep, value = text.partition("=")
        name, value = name.strip(), value.strip()
        if not sep or not name or not value:
            example = "left.yaml" if flag == "--intrinsics" else "'l/*.png'"
            raise ParameterError(f"{flag} {text!r}: expected NAME=VALUE, e.g. "
                                 f"{flag} left={example}")
        if name in out:
            raise ParameterError(f"{flag}: camera {name!r} is given twice")
        out[name] = value
    return out


def _cameras(args: argparse.Namespace, params: dict[str, Any]) -> dict[str, str]:
    """The rig's cameras from ``--camera``, checked against the usage rules."""
    cams = _named(args.camera, "--camera")
    if len(cams) < 2:
        raise ParameterError("a rig needs two or more --camera NAME=...; for one camera give "
                             "the image files or --bag BAG --topic T")
    check = SPECS["cameras"].check
    complaint = check(list(cams)) if check else None
    if complaint:
        raise ParameterError(f"--camera: the names {complaint}")
    listed = list(params["cameras"])
    if listed and listed != list(cams):
        raise ParameterError(f"--camera names {', '.join(cams)} but the parameter 'cameras' is "
                             f"[{', '.join(listed)}]; give the same cameras in the same order")
    for flag, given in (("image files", bool(args.images)), ("--output", bool(args.output)),
                        ("--topic", bool(args.topic))):
        if given:
            raise ParameterError(f"{flag} with --camera: a rig takes its images from each "
                                 "--camera NAME=... and writes --output-dir DIR")
    if not args.output_dir:
        raise ParameterError("--camera needs --output-dir DIR (a YAML per camera and "
                             "camchain.yaml are written there)")
    return cams


def _fixed(args: argparse.Namespace, params: dict[str, Any],
           names: tuple[str, ...]) -> dict[str, Any]:
    """name -> CameraInfoData of ``--intrinsics`` (with calibrate.fix_intrinsics)."""
    from artcal_ros.core.camera_info import read_camera_info_yaml

    given = _named(args.intrinsics, "--intrinsics")
    if not params["calibrate.fix_intrinsics"]:
        if given:
            raise ParameterError("--intrinsics needs --set calibrate.fix_intrinsics=true (the "
                                 "intrinsics are then kept and only the extrinsics solved)")
        return {}
    unknown = [n for n in given if n not in names]
    if unknown:
        raise ParameterError(f"--intrinsics {unknown[0]}=...: no --camera {unknown[0]} "
                             f"(the cameras: {', '.join(names)})")
    missing = [n for n in names if n not in given]
    if missing:
        raise ParameterError(f"calibrate.fix_intrinsics=true needs every camera's intrinsics: "
                             f"give --intrinsics {missing[0]}=YAML"
                             + (f" (missing: {', '.join(missing)})" if len(missing) > 1 else ""))
    infos = {n: read_camera_info_yaml(given[n]) for n in names}
    for n, info in infos.items():
        try:
            info.camera  # noqa: B018 - checks the distortion model is one we solve
        except ArtcalError as e:
            raise ParameterError(f"--intrinsics {n}={given[n]}: {e}") from None
    return infos


def _solve(frames: RigFrames, board: Board, params: dict[str, Any], fixed: dict[str, Any],
           max_views: int | None, say: Any) -> RigResult:
    from artcal_ros.core.calibrate.rig import calibrate_rig

    for n, info in fixed.items():
        if tuple(info.image_size) != frames.sizes[n]:
            raise ParameterError(
                f"--intrinsics {n}: the YAML is for {info.image_size[0]}x{info.image_size[1]} "
                f"images, camera {n}'s are {frames.sizes[n][0]}x{frames.sizes[n][1]}")
    extra: dict[str, Any] = {"max_frames": max_views} if max_views is not None else {}
    return calibrate_rig(frames.detections, board, image_sizes=frames.sizes, progress=say,
                         **rig_solve_kwargs(params, frames.names, fixed), **extra)


def write_outputs(directory: Path, rig: RigResult, topics: dict[str, str]) -> list[str]:
    """DIR/<name>.yaml per camera and DIR/camchain.yaml; returns the camchain's warnings."""
    return write_rig_files(directory, rig, topics)[1]


def summary_dict(rig: RigResult, frames: RigFrames, board: Board) -> dict[str, Any]:
    """The rig's ``summary.json``: the rig's part, each camera's single-camera fields (with
    its tone curve and board check) under ``cameras``."""
    summary: dict[str, Any] = {"success": True, **rig.to_summary_dict()}
    summary["camera_names"] = list(rig.names)
    per_camera: dict[str, Any] = {}
    for n in rig.names:
        res = rig.cameras[n]
        used = [frames.detections[n][i] for i in rig.frames_used]
        check = check_board([d for d in used if d is not None], board, res.camera)
        per_camera[n] = {**res.to_summary_dict(), "rostopic": frames.topics[n],
                         "frames_seen": sum(1 for d in frames.detections[n]
                                            if d is not None and len(d.ids) + len(d.point_ids)),
                         "tone_curve": frames.detectors[n].tone.as_dict(),
                         "board_check": check.as_dict()}
    summary["cameras"] = per_camera
    summary["frames"] = len(frames.detections[rig.names[0]])
    summary["pairing"] = frames.note
    return summary


def write_report(directory: Path, rig: RigResult, frames: RigFrames, board: Board,
                 points: str, progress: Any = None) -> None:
    """summary.json and the rig's report (report.pdf, verdict.png, pair_<a>_<b>.png and each
    camera's pages in ``directory``/<name>/: :mod:`artcal_ros.core.calibrate.rig_report`)."""
    from artcal_ros.core.calibrate.rig_report import write_rig_report

    summary = summary_dict(rig, frames, board)
    try:
        directory.mkdir(parents=True, exist_ok=True)
        (directory / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    except OSError as e:
        raise ArtcalError(f"cannot write the report into {directory}: {e.strerror}") from None
    write_rig_report(directory, rig, frames.detections, board, points,
                     checks=summary["cameras"], progress=progress)


def _refused_report(directory: Path, reason: str, frames: RigFrames) -> None:
    """summary.json with the reason, and report.pdf: the reason in words and each camera's
    coverage of the points it detected."""
    from artcal_ros.core.calibrate.report import write_refused_report

    seen = {n: sum(1 for d in frames.detections[n] if d is not None and len(d.ids)
                   + len(d.point_ids)) for n in frames.names}
    points = {n: np.concatenate([np.asarray(d.points_px if len(d.point_ids) else d.centers_px,
                                            np.float64).reshape(-1, 2)
                                 for d in frames.detections[n] if d is not None] or
                                [np.zeros((0, 2))]) for n in frames.names}
    first, *others = frames.names
    write_refused_report(
        directory, reason, frames.sizes[first], points[first],
        images=len(frames.detections[first]), title=first,
        more_cameras={n: (frames.sizes[n], points[n]) for n in others},
        summary={"success": False, "reason": reason, "camera_names": list(frames.names),
                 "frames": len(frames.detections[first]), "frames_seen": seen,
                 "pairing": frames.note, "warnings": [reason]})


def rig_text(rig: RigResult, frames: RigFrames) -> str:
    """What the command prints: the rig, each pair's extrinsics, each camera."""
    lines = [f"rig {', '.join(rig.names)}: {len(rig.frames_used)} of "
             f"{len(frames.detections[rig.names[0]])} frames used ({frames.note}); "
             f"reprojection RMS {rig.reprojection_rms_px:.3f} px"
             + ("; intrinsics kept (calibrate.fix_intrinsics)" if rig.fixed_intrinsics else "")]
    epi = rig.rectified_epipolar_rms_px
    listed = [(rig.reference, n) for n in rig.names[1:]]
    listed += [p for p in rig.consecutive_pairs if p not in listed]
    for a, b in listed:
        p = rig.pairs[a, b]
        text = (f"{a} -> {b}: baseline {p.baseline_m:.6f} m +- "
                f"{p.baseline_std_m * 1000:.3f} mm, "
                f"rotation {p.rotation_deg:.3f} deg +- "
                f"{float(np.linalg.norm(p.rotation_std_deg)):.3f}, t = "
                f"({', '.join(f'{v:.5f}' for v in p.t)}) m; {p.shared_frames} shared frames")
        if (a, b) in epi:
            text += f"; rectified epipolar RMS {epi[a, b]:.3f} px"
        lines.append(text)
    lines += [f"{n}: {rig.cameras[n].summary_line()}" for n in rig.names]
    lines += [f"warning: {w}" for w in rig.warnings]
    return "\n".join(lines)


def run_rig(args: argparse.Namespace, params: dict[str, Any], board: Board) -> int:
    """``artcal calibrate --camera ...``; see the module docstring for the exit status."""
    cams = _cameras(args, params)
    names = tuple(cams)
    fixed = _fixed(args, params, names)
    if args.max_views is not None and args.max_views < 3:
        raise ParameterError(f"--max-views {args.max_views}: must be at least 3")
    for flag, path in (("--output-dir", args.output_dir), ("--report", args.report)):
        if path:
            check_writable(flag, str(Path(path) / "x"))

    def say(msg: str) -> None:
        if not args.quiet:
            print(f"calibrate: {msg}", file=sys.stderr)

    def warn(msg: str) -> None:
        print(f"artcal calibrate: warning: {msg}", file=sys.stderr)

    start = time.monotonic()
    skipped = SkippedFrames()
    if args.bag:
        frames = bag_frames(args.bag, cams, board, params, max_frames=args.max_frames,
                            budget_s=args.time_budget, quiet=args.quiet, skipped=skipped,
                            warn=warn)
    else:
        frames = folder_frames(cams, board, params, quiet=args.quiet, skipped=skipped)
    say(frames.note)
    if skipped.count:
        warn(skipped.summary())
    try:
        rig = _solve(frames, board, params, fixed, args.max_views, say)
    except CalibrationError as e:
        reason = str(e)
        if args.report:
            _refused_report(Path(args.report), reason, frames)
            reason += f" (report written to {args.report})"
        raise CalibrationError(reason) from None
    out = Path(args.output_dir).expanduser()
    for w in write_outputs(out, rig, frames.topics):
        warn(w)
    if args.report:
        write_report(Path(args.report), rig, frames, board, str(params["points"]), say)
    print(rig_text(rig, frames))
    written = [str(out / f"{n}.yaml") for n in names] + [str(out / "camchain.yaml")]
    print(f"wrote {', '.join(written)} ({time.monotonic() - start:.1f} s)")
    if skipped.count:
        print(skipped.summary())
    return 0
