"""Declare the calibrator's parameters on a node from the one table in core.params.

Every parameter comes from :data:`artcal_ros.core.params.PARAMETERS`, with its
description, allowed values and a read-only flag for the ones that change what
the collected views mean (board, points, model, transport). Values are typed
dynamically and checked by :func:`artcal_ros.core.params.validate`, so
``-p board.marker_length:=1`` (an integer for a float) is accepted, while
``-p board.cols:=-1`` is refused with a message naming the parameter. The ``calibrate.*``
options (what the solve estimates) may be changed at run time: the next ``~/calibrate``
uses them, on the views already collected.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from artcal_ros.core.errors import ParameterError
from artcal_ros.core.params import PARAMETERS, ParamValue, validate

# Changing these would invalidate the views already collected, or the subscription made at
# start-up: restart the node instead.
READ_ONLY = frozenset(s.name for s in PARAMETERS if s.name.startswith("board.")
                      or s.name in ("points", "camera_model", "image_transport", "image_qos",
                                   "resume", "cameras"))


def _descriptor(name: str) -> ParameterDescriptor:
    spec = next(s for s in PARAMETERS if s.name == name)
    kind = {bool: "bool", int: "integer", float: "number (metres where a length)",
            str: "string", list: "string array"}[type(spec.default)]
    constraints = (f"one of: {', '.join(spec.choices)}" if spec.choices
                   else f"{kind}: {spec.allowed}" if spec.allowed else kind)
    return ParameterDescriptor(
        name=name, description=spec.description, additional_constraints=constraints,
        read_only=name in READ_ONLY, dynamic_typing=True)


def declare_parameters(node: Node) -> dict[str, ParamValue]:
    """Declare every calibrator parameter on ``node`` and return the validated values.

    Unknown parameters given to the node are logged as warnings (a typo would otherwise
    be ignored silently).

    Raises:
        ParameterError: a value is bad; the message names the parameter.
    """
    for spec in PARAMETERS:
        node.declare_parameter(spec.name, spec.default, _descriptor(spec.name))
    values: dict[str, Any] = {s.name: node.get_parameter(s.name).value for s in PARAMETERS}
    overrides = getattr(node, "_parameter_overrides", {}) or {}
    known = {s.name for s in PARAMETERS} | set(node._parameters)
    for name in sorted(set(overrides) - known):
        node.get_logger().warning(f"ignoring unknown parameter '{name}'")
    checked = validate(values)
    if int(checked["max_views"]) < int(checked["min_views"]):
        raise ParameterError(f"parameter 'max_views': {checked['max_views']} is below "
                             f"min_views ({checked['min_views']}); raise it or lower min_views")
    return checked


def check_update(current: dict[str, ParamValue], changes: list[Parameter]) -> tuple[
        dict[str, ParamValue] | None, SetParametersResult]:
    """Validate a runtime parameter change.

    Args:
        current: the node's validated values now.
        changes: the parameters being set.

    Returns:
        (the new values or None if refused, the result to answer rclpy with).
    """
    values: dict[str, Any] = dict(current)
    for p in changes:
        if p.name in values:
            values[p.name] = p.value
    try:
        checked = validate(values)
        if int(checked["max_views"]) < int(checked["min_views"]):
            raise ParameterError("parameter 'max_views' must be >= min_views")
    except ParameterError as e:
        return None, SetParametersResult(successful=False, reason=str(e))
    return checked, SetParametersResult(successful=True)
