"""``artcal detect``: find the board's markers and points in images; write them as JSON.

    artcal detect frames/*.png --params config/calibrator.yaml --json detections.json
    artcal detect img.png --set board.polarity=mixed --json out.json --overlay overlays/
    artcal detect left*.jpg --size 9x6 --square 0.025 --json chess.json   # a chessboard
    artcal detect img*.jpg --pattern charuco --size 5x7 --square 0.04 \\
        --charuco_marker_size 0.03 --aruco_dict 6x6_250 --json charuco.json
    artcal detect frames/*.png --target april_6x6.yaml --json tags.json     # a Kalibr target

The JSON file is ``{"images": [{"file", "width", "height", "markers": [{"id",
"corners": [[x, y] x 4], "center": [x, y]}]}]}`` in OpenCV pixel coordinates
(the centre of the top-left pixel is (0, 0)); corners run TL, TR, BR, BL on the
board. Chessboard and ChArUco boards add ``"points": [{"id", "xy": [x, y]}]`` per image,
``id`` the point's index in the board's object points (OpenCV's charuco corner ids,
``findChessboardCorners`` order). ``--overlay DIR`` writes one PNG per image with each
marker's quad, id, corners and centre, and each point with its id, drawn on it.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
from typing import Any

import cv2

from artcal_ros.cli.common import (
    add_board_arguments,
    add_params_arguments,
    board_overrides,
    params_from_args,
)
from artcal_ros.cli.detect_overlay import draw_detections
from artcal_ros.cli.skipped import SkippedFrames, expand_image_paths, read_image_file
from artcal_ros.core.board import Board
from artcal_ros.core.detect import Detector, DetectorConfig
from artcal_ros.core.detections import tag_corner_points
from artcal_ros.core.errors import ImageFormatError, ParameterError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``artcal detect``."""
    parser.add_argument("images", nargs="+", metavar="IMAGE",
                        help="image files (PNG, JPEG, TIFF, ...; 8 or 16 bit, grey or colour)")
    add_params_arguments(parser)
    add_board_arguments(parser)
    parser.add_argument("--json", required=True, metavar="OUT.json",
                        help="where to write the detections")
    parser.add_argument("--overlay", metavar="DIR", default=None,
                        help="also write <DIR>/<image name>.png with the detections drawn")
    parser.add_argument("--quiet", action="store_true",
                        help="print only the totals, not a line per image")


# the image reader of every verb (an image per file, errors naming the file)
read_image = read_image_file


def _found(board: Board, markers: int, points: int) -> str:
    """``12 markers``, or ``54 points`` (and ``and 17 markers`` where the board has both)."""
    if board.has_points or board.board_type == "aprilgrid":
        return f"{points} points" + (f" and {markers} markers" if board.n_markers else "")
    return f"{markers} markers"


def run(args: argparse.Namespace) -> int:
    """Detect in every image, write the JSON (and overlays); print a line per image (unless
    ``--quiet``) and a one-line summary.

    Images that cannot be read are skipped, counted and named in the summary; only when
    none can be read is it an error (exit 2).
    """
    params = params_from_args(args, board_overrides(args))
    board = Board.from_params(params)
    detector = Detector(board, DetectorConfig.from_params(params))
    paths = expand_image_paths(list(args.images))
    out_json = Path(args.json)
    if out_json.parent and not out_json.parent.is_dir():
        raise ParameterError(f"--json {args.json}: directory {out_json.parent} does not exist")
    overlay_dir = Path(args.overlay) if args.overlay else None
    if overlay_dir is not None:
        try:
            overlay_dir.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise ParameterError(f"--overlay {args.overlay}: cannot create it: "
                                 f"{e.strerror or e}") from None
    records: list[dict[str, Any]] = []
    skipped = SkippedFrames()
    total = 0
    points = 0
    for path in paths:
        try:
            image = read_image_file(path)
        except ImageFormatError as e:
            skipped.add(e)
            if not args.quiet:
                print(e)
            continue
        dets = detector.detect(image, source=path)
        listed = tag_corner_points(dets, board) if board.board_type == "aprilgrid" else dets
        records.append(listed.to_json(file=path, with_points=board.has_points))
        total += len(dets)
        points += len(listed.point_ids)
        if not args.quiet:
            print(f"{path}: {_found(board, len(dets), len(listed.point_ids))}")
        if overlay_dir is not None:
            name = overlay_dir / (Path(path).stem + ".png")
            if not cv2.imwrite(str(name), draw_detections(image, dets)):
                raise ParameterError(f"--overlay {args.overlay}: cannot write {name}")
    if not records:
        raise ImageFormatError(f"no usable image: {skipped.summary()}")
    tmp = out_json.with_name(out_json.name + ".tmp")
    try:
        tmp.write_text(json.dumps({"images": records}, indent=1) + "\n")
        os.replace(tmp, out_json)
    except OSError as e:
        raise ParameterError(f"--json {args.json}: cannot write it: {e.strerror or e}") from None
    line = f"wrote {args.json}: {_found(board, total, points)} in {len(records)} image(s)"
    print(line + (f"; {skipped.summary()}" if skipped.count else ""))
    return 0
