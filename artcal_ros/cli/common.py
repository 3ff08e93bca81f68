"""Argument helpers shared by the ``artcal`` verbs."""

from __future__ import annotations

import argparse
from typing import Any

from artcal_ros.core.params import ParamValue, load_params, parse_override


def add_params_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--params P`` and ``--set KEY=VALUE`` (repeatable)."""
    parser.add_argument("--params", metavar="P", default=None,
                        help="ROS 2 parameters file (e.g. config/calibrator.yaml)")
    parser.add_argument("--set", metavar="KEY=VALUE", action="append", default=[],
                        help="override one parameter, e.g. --set board.cols=10 (repeatable)")


def params_from_args(args: argparse.Namespace) -> dict[str, ParamValue]:
    """Parameters from ``--params`` with the ``--set`` overrides applied (validated)."""
    overrides: dict[str, Any] = dict(parse_override(s) for s in args.set)
    return load_params(args.params, overrides)
