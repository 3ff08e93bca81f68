"""Parameters shared by the node and the CLI: names, defaults, validation.

One table (:data:`PARAMETERS`) declares every parameter once, with its type,
default and a description; the ROS node declares its parameters from it and
the CLI reads the same ROS 2 parameters file. Values are kept in a flat dict
keyed by the dotted ROS name (``{"board.cols": 19, ...}``).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from artcal_ros.core.board.aprilgrid import aprilgrid_complaint
from artcal_ros.core.board.dictionaries import predefined_code, predefined_names
from artcal_ros.core.board.types import BUILT_TYPES, PLANNED_TYPES
from artcal_ros.core.camera import MODELS
from artcal_ros.core.errors import ParameterError

ParamValue = bool | int | float | str
# The flat parameters: ParamValue each, ``cameras`` a list of names.
Params = dict[str, Any]


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: its dotted name, default, description and allowed values."""

    name: str
    default: ParamValue | list[str]
    description: str
    choices: tuple[str, ...] = ()
    check: Callable[[Any], str | None] | None = None  # returns a complaint or None
    allowed: str = ""  # the allowed values in words, where neither choices nor type say it


def _positive(value: Any) -> str | None:
    return None if value > 0 else "must be > 0"


def _non_negative(value: Any) -> str | None:
    return None if value >= 0 else "must be >= 0"


def _a_name(value: Any) -> str | None:
    return None if str(value).strip() else "must not be empty"


def _camera_names(value: Any) -> str | None:
    names = list(value)
    if len(names) == 1:
        return ("names one camera; give none (one camera on 'image') or two or more, "
                "e.g. [left, right]")
    for name in names:
        if not name or not all(c.isalnum() or c == "_" for c in name) or name[0].isdigit():
            return (f"has {name!r}, not a camera name (letters, digits and _, not starting "
                    "with a digit: it becomes a topic and a file name)")
    if len(set(names)) != len(names):
        return "names a camera twice"
    return None


def _board_type(value: Any) -> str | None:
    if value in BUILT_TYPES:
        return None
    if value in PLANNED_TYPES:
        return f"is not built yet; {', '.join(PLANNED_TYPES)} are planned"
    return "is not a board type"


def _dictionary(value: Any) -> str | None:
    if str(value) == "tag36h11":  # an aprilgrid's (Kalibr's name)
        return None
    if predefined_code(str(value)) is not None:
        return None
    return f"is not an OpenCV predefined dictionary; allowed: {', '.join(predefined_names())}"


def length_complaint(value_m: float) -> str | None:
    """Why a board length of ``value_m`` metres is implausible (a mistaken unit), or None.

    Over 1 m is most likely millimetres or centimetres typed as metres; under 1 mm is
    finer than a printer prints or a camera resolves at calibration distances.
    """
    if value_m > 1.0:
        hint = f"{value_m:g} mm is {value_m / 1000:g}"
        if value_m < 100:
            hint += f", {value_m:g} cm is {value_m / 100:g}"
        return f"{value_m:g} m? lengths are in metres ({hint})"
    if 0 < value_m < 0.001:
        return (f"{value_m * 1000:g} mm is too small to print or detect; lengths are in "
                "metres (25 mm is 0.025)")
    return None


# How each range check reads after "expected an integer" or "expected a number".
_RANGE_WORDS: dict[Any, str] = {_positive: " > 0", _non_negative: " >= 0"}


PARAMETERS: tuple[ParamSpec, ...] = (
    ParamSpec("board.type", "marker_grid",
              "Board layout: marker_grid (self-identifying markers), chessboard "
              "(camera_calibration's), charuco (OpenCV's CharucoBoard), aprilgrid (Kalibr's "
              "AprilGrid), circles and acircles (OpenCV's symmetric and asymmetric circle "
              "grids).",
              check=_board_type, allowed=", ".join(BUILT_TYPES)),
    ParamSpec("board.dictionary", "DICT_6X6_1000",
              "OpenCV predefined ArUco dictionary name of the markers (aprilgrid: tag36h11, "
              "the only one it prints).", check=_dictionary),
    ParamSpec("board.cols", 19, "Per row: markers (marker_grid), tags (aprilgrid: Kalibr's "
              "tagCols), inner corners (chessboard, "
              "camera_calibration's --size COLSxROWS), squares (charuco, OpenCV's squaresX), "
              "circles (circles, acircles: findCirclesGrid's patternSize width).",
              check=_positive),
    ParamSpec("board.rows", 9, "Per column: markers (marker_grid), tags (aprilgrid: "
              "tagRows), inner corners "
              "(chessboard), squares (charuco, OpenCV's squaresY), circle rows (circles, "
              "acircles).", check=_positive),
    ParamSpec("board.marker_length", 0.06,
              "Side of a marker's outer black square, metres (aprilgrid: Kalibr's tagSize).",
              check=_positive),
    ParamSpec("board.marker_separation", 0.02,
              "Gap between neighbouring markers, metres (aprilgrid: tagSize x tagSpacing).",
              check=_positive),
    ParamSpec("board.square_length", 0.08,
              "Side of a chessboard or charuco square; circles, acircles: the circle spacing "
              "(findCirclesGrid's squareSize; circles of 0.4 x spacing diameter), metres.",
              check=_positive),
    ParamSpec("board.legacy_pattern", False,
              "charuco: OpenCV's legacy layout (before 4.6: a white top-left square on boards "
              "with an even number of rows; CharucoBoard.setLegacyPattern)."),
    ParamSpec("board.first_id", 0, "Id of the top-left marker; ids run row-major.",
              check=_non_negative),
    ParamSpec("board.polarity", "black",
              "black: black border on white; white: the reverse; mixed: alternating like a "
              "chequerboard; any: detect both.", choices=("black", "white", "mixed", "any")),
    ParamSpec("points", "corners", "Correspondences per marker: its 4 corners or its centre.",
              choices=("centers", "corners")),
    ParamSpec("camera_model", "plumb_bob", "Lens model to solve for.",
              choices=MODELS),
    # What the solve estimates, as ROS camera_calibration's flags; node and CLI alike.
    ParamSpec("calibrate.k_coefficients", 0,
              "Radial distortion terms solved, k1..kN (camera_calibration's --k-coefficients); "
              "0: the model's default (k1 k2 for plumb_bob, all for the others). The terms "
              "not solved are zero.", check=_non_negative,
              allowed="0, or 1 to 3 (plumb_bob), 1 to 6 (rational_polynomial), "
                      "1 to 4 (equidistant)"),
    ParamSpec("calibrate.fix_principal_point", False,
              "Hold the principal point at the image centre, cx = (width - 1) / 2, "
              "cy = (height - 1) / 2 (pixel centres at integers)."),
    ParamSpec("calibrate.fix_aspect_ratio", False,
              "Solve one focal length: fx = fy (square pixels)."),
    ParamSpec("calibrate.zero_tangent_dist", False,
              "Hold the tangential distortion at zero, p1 = p2 = 0 (plumb_bob and "
              "rational_polynomial; equidistant has none)."),
    ParamSpec("calibrate.fix_intrinsics", False,
              "A rig: keep the given cameras' intrinsics (their camera_info YAMLs) and solve "
              "only the extrinsics."),
    ParamSpec("detector.gamma", 0.0,
              "Tone curve of the images: 0 estimates it from the board's edges; > 0 fixes "
              "linear = value ** gamma (2.2 sRGB-like, 1.0 linear).", check=_non_negative),
    ParamSpec("camera_name", "camera", "Name written into the calibration file.",
              check=_a_name, allowed="a non-empty name"),
    ParamSpec("output_file", "",
              "Calibration YAML to write; empty means ~/.ros/camera_info/<camera_name>.yaml.",
              allowed="a file path, or empty"),
    ParamSpec("commit", False, "Send the result to the camera driver's set_camera_info."),
    ParamSpec("cameras", [],
              "Empty: one camera on 'image'. Two or more names, e.g. [left, right]: a rig, one "
              "image topic per camera (left/image, right/image), solved together.",
              check=_camera_names, allowed="[] or two or more names, e.g. [left, right]"),
    ParamSpec("sync_tolerance", 0.01,
              "Seconds: images of different cameras of a rig within it form one rig frame "
              "(camera_calibration's --approximate).", check=_positive),
    # Node-only: how the calibrator node listens and when it may solve.
    ParamSpec("image_transport", "raw",
              "raw: subscribe sensor_msgs/Image on 'image'; compressed: "
              "sensor_msgs/CompressedImage on 'image/compressed'.", choices=("raw", "compressed")),
    ParamSpec("image_qos", "auto",
              "Reliability of the image subscription. auto: reliable when every publisher of "
              "the topic is reliable, else best effort (as ros2 topic echo and rosbag2 "
              "choose), chosen again when publishers come and go; reliable or best_effort "
              "force it.", choices=("auto", "reliable", "best_effort")),
    ParamSpec("min_views", 10, "Views the node collects before ~/calibrate will solve.",
              check=_positive),
    ParamSpec("max_views", 40, "Views a solve uses at most (the most informative are chosen).",
              check=_positive),
    ParamSpec("readiness.max_uncertainty", 0.1,
              "The node is ready when min_views are collected and the projection uncertainty "
              "(1-sigma, RMS over the whole image, from the live solve) is at or below this, "
              "pixels.", check=_positive, allowed="a number of pixels > 0, e.g. 0.1"),
    ParamSpec("report_dir", "",
              "Where the node writes the report (report.pdf, its pages as PNG, summary.json) "
              "after every successful solve; empty means ~/.ros/artcal/<camera_name>/report/.",
              allowed="a directory path, or empty"),
    ParamSpec("overlay.max_width", 960,
              "Width the node's ~/overlay image is scaled down to at most, pixels (a 1080p bgr8 "
              "overlay is 6.2 MB a message, 1.6 MB at 960 px).",
              check=_positive),
    ParamSpec("resume", False,
              "true: continue the session saved under ~/.ros/artcal/<camera_name>/ (the "
              "views collected before a stop, crash or kill); false: start empty (a saved "
              "session is kept as session.previous.npz once new views are saved)."),
)

SPECS: dict[str, ParamSpec] = {s.name: s for s in PARAMETERS}


def _k_coefficients_fit_model(values: Mapping[str, ParamValue]) -> str | None:
    # The range depends on camera_model; the solve's table of lens models says it.
    from artcal_ros.core.calibrate.model import k_coefficients_complaint

    return k_coefficients_complaint(str(values["camera_model"]),
                                    int(values["calibrate.k_coefficients"]))


# The lengths each board type prints (the others are unused and not checked).
_LENGTHS_USED = {
    "marker_grid": ("board.marker_length",), "aprilgrid": ("board.marker_length",),
    "charuco": ("board.square_length", "board.marker_length"),
    "chessboard": ("board.square_length",), "circles": ("board.square_length",),
    "acircles": ("board.square_length",),
}


def _lengths_in_metres(values: Mapping[str, ParamValue]) -> str | None:
    for name in _LENGTHS_USED.get(str(values["board.type"]), ()):
        complaint = length_complaint(float(values[name]))
        if complaint:
            return f"parameter '{name}': {complaint}"
    return None


def _board_fits(values: Mapping[str, ParamValue]) -> str | None:
    kind = values["board.type"]
    if kind == "marker_grid":
        return None
    if kind == "aprilgrid":
        return aprilgrid_complaint(str(values["board.dictionary"]), str(values["board.polarity"]),
                                   int(values["board.first_id"]))
    for name in ("board.cols", "board.rows"):
        if int(values[name]) < 2:
            what = {"chessboard": "inner corners", "charuco": "squares"}.get(str(kind),
                                                                             "circles")
            return (f"parameter '{name}': {values[name]} is too few for a {kind} board; "
                    f"use at least 2 ({what})")
    if kind == "charuco":
        ml, sl = float(values["board.marker_length"]), float(values["board.square_length"])
        if not ml < sl:
            return (f"parameter 'board.marker_length': {ml} m must be smaller than "
                    f"board.square_length ({sl} m) on a charuco board")
        if values["board.polarity"] != "black":
            return (f"parameter 'board.polarity': {values['board.polarity']!r}; a charuco "
                    "board prints black markers on white squares: use black")
    return None


# Checks that involve several parameters: each returns the whole complaint (naming the
# parameter and its allowed values) or None.
CROSS_CHECKS: tuple[Callable[[Mapping[str, ParamValue]], str | None], ...] = (
    _k_coefficients_fit_model,
    _lengths_in_metres,
    _board_fits,
)


def defaults() -> Params:
    """Every parameter at its default value (a list default is a fresh copy)."""
    return {s.name: list(s.default) if isinstance(s.default, list) else s.default
            for s in PARAMETERS}


def allowed_text(spec: ParamSpec) -> str:
    """The values ``spec`` allows, in words: ``true or false``, ``an integer > 0``, ..."""
    want = type(spec.default)
    if spec.choices:
        return "one of " + ", ".join(spec.choices)
    if want is bool:
        return "true or false"
    if want is list:
        return f"a list of names ({spec.allowed})" if spec.allowed else "a list of names"
    words = {int: "an integer", float: "a number"}.get(want, "a string")
    text = words + _RANGE_WORDS.get(spec.check, "")
    return f"{text} ({spec.allowed})" if spec.allowed else text


def _coerce(spec: ParamSpec, value: Any) -> ParamValue | list[str]:
    want = type(spec.default)
    wrong = ParameterError(
        f"parameter '{spec.name}': expected {allowed_text(spec)}, got {value!r}")
    if want is bool:
        if isinstance(value, bool):
            return value
        if isinstance(value, str) and value.lower() in ("true", "false"):
            return value.lower() == "true"
        raise wrong
    if want is str and value is None:  # YAML's empty value: ``output_file:``
        return ""
    if want is list:
        if value is None:   # YAML's empty value, and ROS's for an empty list (no type)
            return []
        if isinstance(value, list | tuple) and all(isinstance(v, str) for v in value):
            return [str(v).strip() for v in value]
        raise wrong
    if isinstance(value, bool | list | dict | tuple | set) or value is None:
        raise wrong
    if want is str:
        return str(value)
    try:
        f = float(value)
    except (TypeError, ValueError, OverflowError):
        raise wrong from None
    if not math.isfinite(f) or (want is int and f != int(f)):
        raise wrong
    return int(f) if want is int else f


def validate(values: Mapping[str, Any]) -> Params:
    """Return a complete, type-checked copy of ``values`` (missing names take defaults).

    Raises:
        ParameterError: naming the first unknown or bad parameter.
    """
    out = defaults()
    for name, value in values.items():
        spec = SPECS.get(name)
        if spec is None:
            raise ParameterError(
                f"unknown parameter '{name}'; known: {', '.join(sorted(SPECS))}")
        v = _coerce(spec, value)
        if spec.choices and v not in spec.choices:
            raise ParameterError(
                f"parameter '{name}': {v!r} is not one of {', '.join(spec.choices)}")
        if isinstance(v, str) and "\n" in v:
            raise ParameterError(f"parameter '{name}': {v!r} must be one line")
        if spec.check is not None:
            complaint = spec.check(v)
            if complaint:
                allowed = f" (allowed: {spec.allowed})" if spec.allowed else ""
                raise ParameterError(f"parameter '{name}': {v!r} {complaint}{allowed}")
        out[name] = v
    for cross in CROSS_CHECKS:
        complaint = cross(out)
        if complaint:
            raise ParameterError(complaint)
    return out


def _flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            flat.update(_flatten(value, name + "."))
        else:
            flat[name] = value
    return flat


def load_params(path: str | os.PathLike[str] | None = None,
                overrides: Mapping[str, Any] | None = None) -> Params:
    """Read a ROS 2 parameters file (``/**: ros__parameters: ...``) into a flat dict.

    Args:
        path: the YAML file; None gives the defaults.
        overrides: values that replace the file's, by dotted name.

    Returns:
        ``{"board.cols": 19, ...}`` with every known parameter present.

    Raises:
        ParameterError: the file cannot be read, or a value is bad (the message names it).
    """
    values: dict[str, Any] = {}
    if path is not None:
        try:
            text = Path(path).read_text()
        except OSError as e:
            raise ParameterError(f"cannot read parameters file {path}: {e.strerror}") from None
        try:
            doc = yaml.safe_load(text) or {}
        except yaml.YAMLError as e:
            raise ParameterError(f"parameters file {path} is not valid YAML: {e}") from None
        if not isinstance(doc, Mapping):
            raise ParameterError(f"parameters file {path}: expected a mapping at the top")
        for node_block in doc.values():
            if isinstance(node_block, Mapping) and "ros__parameters" in node_block:
                values.update(_flatten(node_block["ros__parameters"] or {}))
        if not values and doc:
            # A plain (non-ROS) mapping of parameters is accepted too.
            values.update(_flatten(doc))
    values.update(overrides or {})
    return validate(values)


def parse_override(text: str) -> tuple[str, Any]:
    """Parse a ``KEY=VALUE`` command-line override; VALUE is read as YAML (1, 0.5, true)."""
    if "=" not in text:
        raise ParameterError(f"--set expects KEY=VALUE, got {text!r}")
    key, raw = text.split("=", 1)
    try:
        value = yaml.safe_load(raw) if raw else ""
    except yaml.YAMLError:
        value = raw
    return key.strip(), value


def report_path(params: Mapping[str, Any]) -> Path:
    """The node's report directory: ``report_dir``, or ``report/`` beside the saved session
    (``$ROS_HOME/artcal/<camera_name>/``, ``~/.ros/artcal/<camera_name>/`` by default)."""
    from artcal_ros.core.files import ros_home

    explicit = str(params.get("report_dir") or "")
    if explicit:
        return Path(os.path.expanduser(explicit))
    return ros_home() / "artcal" / str(params.get("camera_name", "camera")) / "report"


def output_path(params: Mapping[str, Any]) -> Path:
    """The calibration file to write: ``output_file`` or ~/.ros/camera_info/<camera_name>.yaml."""
    explicit = str(params.get("output_file") or "")
    if explicit:
        return Path(os.path.expanduser(explicit))
    return Path.home() / ".ros" / "camera_info" / f"{params.get('camera_name', 'camera')}.yaml"
