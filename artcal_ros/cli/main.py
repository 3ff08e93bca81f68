"""The ``artcal`` command: board, synth, detect and calibrate, offline.

Exit status: 0 on success, 1 when a calibration could not be made (with the
reason), 2 on bad usage or input (with the reason). A user's mistake prints one
line, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from artcal_ros.core.errors import ArtcalError, CalibrationError

# verb -> module under artcal_ros.cli with add_arguments(parser) and run(args) -> int
VERBS = {
    "board": "Render a printable board at exact physical scale (PDF, SVG or PNG).",
    "synth": "Render synthetic frames with exact ground truth (PNGs + truth.json, or a bag).",
    "detect": "Detect markers in images; write their corners and centres as JSON.",
    "calibrate": "Calibrate a camera from images or a rosbag2 recording.",
}


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every verb."""
    parser = argparse.ArgumentParser(
        prog="artcal", description="Camera calibration from self-identifying marker boards.")
    sub = parser.add_subparsers(dest="verb", required=True, metavar="VERB")
    for verb, text in VERBS.items():
        module = importlib.import_module(f"artcal_ros.cli.{verb}")
        p = sub.add_parser(verb, help=text, description=text)
        module.add_arguments(p)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``artcal`` console script."""
    args = build_parser().parse_args(argv)
    module = importlib.import_module(f"artcal_ros.cli.{args.verb}")
    try:
        return int(module.run(args))
    except CalibrationError as e:
        print(f"artcal {args.verb}: calibration failed: {e}", file=sys.stderr)
        return 1
    except ArtcalError as e:
        print(f"artcal {args.verb}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"artcal {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
