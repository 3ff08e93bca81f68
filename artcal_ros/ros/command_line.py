"""The nodes' own command line: ``--help``, a stray argument, ROS arguments rclpy refuses.

A node's arguments are ROS's (``--ros-args ... [--]``, which rclpy reads) and the node's own,
outside those blocks. The nodes take no argument of their own but ``-h`` / ``--help``, which
lists the parameters with their defaults and exits 0 before rclpy starts; ``--help`` inside
``--ros-args`` does the same (rcl has no help of its own and rclpy would refuse the flag).
Anything else outside a ROS block is refused with one line and exit status 2, as is a ROS
argument rclpy does not know.

::

    status = handle_arguments(sys.argv if args is None else args, HELP)
    if status is not None:
        return status
    if not init_ros(args, HELP.program, signal_handler_options=...):
        return 2
"""

from __future__ import annotations

import re
import sys
import textwrap
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, TextIO

from artcal_ros.core.params import ParamSpec, allowed_text

HELP_FLAGS = ("-h", "--help")
ROS_ARGS = "--ros-args"
WIDTH = 99

# rcl's arguments, in its words; printed by ``--help`` since rcl prints none itself.
ROS_ARGUMENTS = (
    ("-p, --param NAME:=VALUE", "set a parameter (VALUE read as YAML: 1, 0.5, true, [a, b])"),
    ("--params-file FILE", "parameters from a ROS 2 parameters file (/**: ros__parameters:)"),
    ("-r, --remap FROM:=TO", "remap a name: image:=/camera/image_raw, __node:=NAME, __ns:=/NS"),
    ("--log-level [LOGGER:=]LEVEL", "debug, info, warn, error or fatal"),
    ("--log-config-file FILE", "a logging configuration file"),
    ("--enable-rosout-logs, --disable-rosout-logs", "log to /rosout or not"),
    ("--enable-stdout-logs, --disable-stdout-logs", "log to the console or not"),
    ("-e, --enclave ENCLAVE", "the security enclave"),
    ("--", "ends the ROS arguments"),
)


@dataclass(frozen=True)
class ParamHelp:
    """One parameter as ``--help`` lists it."""

    name: str
    default: Any
    description: str
    allowed: str = ""  # the values allowed, in words (empty: the description says it)


@dataclass(frozen=True)
class CommandHelp:
    """What ``--help`` prints for one node executable.

    Attributes:
        program: the executable's name (``calibrator``).
        summary: one or two sentences: what the node does.
        parameters: every parameter it declares, in the order to list them.
        example: a typical command line.
    """

    program: str
    summary: str
    parameters: tuple[ParamHelp, ...]
    example: str


def from_specs(specs: Iterable[ParamSpec]) -> tuple[ParamHelp, ...]:
    """The help entries of :data:`artcal_ros.core.params.PARAMETERS`-style specs (a plain
    string's "a string" left out: the default shows it)."""
    return tuple(ParamHelp(s.name, s.default, s.description,
                           "" if allowed_text(s) == "a string" else allowed_text(s))
                 for s in specs)


def split_arguments(args: Sequence[str]) -> tuple[list[str], list[str]]:
    """(the node's own arguments, the ROS arguments) of ``args`` (without the program name).

    ROS arguments are those after ``--ros-args`` up to a ``--`` or the end; there may be
    several such blocks. The markers themselves are in neither list.
    """
    own: list[str] = []
    ros: list[str] = []
    inside = False
    for arg in args:
        if arg == ROS_ARGS:
            inside = True
        elif inside and arg == "--":
            inside = False
        else:
            (ros if inside else own).append(arg)
    return own, ros


def _value(default: Any) -> str:
    if isinstance(default, bool):
        return str(default).lower()
    if isinstance(default, (list, tuple)):
        return "[" + ", ".join(str(v) for v in default) + "]"
    if isinstance(default, str) and not default:
        return "''"
    return str(default)


def help_text(command: CommandHelp) -> str:
    """The whole ``--help`` text: usage, summary, parameters with defaults, ROS arguments."""
    wrap = textwrap.TextWrapper(width=WIDTH, initial_indent="      ",
                                subsequent_indent="      ")
    lines = [f"usage: {command.program} [-h] [--ros-args [-p NAME:=VALUE]... "
             "[--params-file FILE] [-r FROM:=TO]... [--]]", ""]
    lines += textwrap.wrap(command.summary, WIDTH)
    lines += ["", f"example: {command.example}", "",
              "parameters (set with --ros-args -p NAME:=VALUE, or in a --params-file):"]
    for p in command.parameters:
        lines.append(f"  {p.name} (default {_value(p.default)})")
        lines += wrap.wrap(p.description)
        if p.allowed:
            lines += wrap.wrap(f"allowed: {p.allowed}")
    lines += ["", f"ROS arguments (after {ROS_ARGS}):"]
    for flags, text in ROS_ARGUMENTS:
        lines.append(f"  {flags}")
        lines += wrap.wrap(text)
    return "\n".join(lines) + "\n"


def handle_arguments(argv: Sequence[str], command: CommandHelp, *,
                     out: TextIO | None = None, err: TextIO | None = None) -> int | None:
    """Answer ``--help`` and refuse a stray argument before any ROS start-up.

    Args:
        argv: the whole command line, program name first (``sys.argv``).
        command: what to print for ``--help``.
        out, err: where help and errors go (default: stdout, stderr).

    Returns:
        None to go on and start the node; else the exit status (0 after the help, 2 after
        one line naming an argument the node does not take).
    """
    own, ros = split_arguments(argv[1:])
    if any(a in HELP_FLAGS for a in [*own, *ros]):
        (out or sys.stdout).write(help_text(command))
        return 0
    if own:
        (err or sys.stderr).write(
            f"{command.program}: unknown argument {own[0]!r}: the node's settings are ROS "
            f"parameters ({command.program} {ROS_ARGS} -p NAME:=VALUE); "
            f"{command.program} --help lists them\n")
        return 2
    return None


def init_ros(args: list[str] | None, program: str, **options: Any) -> bool:
    """``rclpy.init(args=args, **options)``; False after one line on stderr when rcl refuses
    the ROS arguments: an unknown one (rclpy's ``UnknownROSArgsError``) or one it cannot parse
    (``RCLError``, e.g. a ``-p`` without ``NAME:=VALUE``). Both are RuntimeErrors."""
    import rclpy

    try:
        rclpy.init(args=args, **options)
    except RuntimeError as e:
        # Matched by name: rclpy defines both classes only in its private binding module.
        kind = type(e).__name__
        if kind == "UnknownROSArgsError":
            # Its text is the list of the arguments rcl did not know: "['--foo', 'x']".
            reason = f"unknown ROS argument(s) {str(e).strip().strip('[]') or '?'}"
        elif kind == "RCLError":
            # "failed to initialize rcl: <reason>, at <source file>:<line>"
            reason = re.sub(r"(, at \S+:\d+)+$", "", str(e).strip().splitlines()[0])
        else:
            raise
        sys.stderr.write(f"{program}: {reason}; {program} --help lists the ROS arguments\n")
        return False
    return True
