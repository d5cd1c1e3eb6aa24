"""The node's parameters at start-up and at run time: declared from :data:`cgp_sim_ros.interface.PARAMETERS`,
checked with a reason that names the parameter, converted.

- At start-up (:func:`read_parameters`): a value the node cannot start with is a :class:`ConfigError`
  (``cgp-sim`` exits with status 2 and the reason); an override of a parameter the node does not have is
  warned about (a typo), not fatal (parameter files may address many nodes).
- At run time (:func:`refusal`): the node's parameter callback refuses a change with the reason.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterTypeException

from .. import interface as itf

#: parameters rclpy itself declares or reads; an override of these is not "unknown"
ROS_OWN_PARAMETERS = ("use_sim_time", "start_type_description_service")


class ConfigError(ValueError):
    """A parameter value or scene the node cannot start with."""


def read_parameters(node, overrides: Mapping) -> dict:
    """Declare every parameter on ``node`` and return their values by name, checked and converted (a float
    parameter given as an integer is a float); raises :class:`ConfigError` with every problem.  ``overrides``:
    the node's parameter overrides (name → rclpy ``Parameter``), for the reasons and the unknown names."""
    problems = _declare(node, overrides)
    values = {p.name: node.get_parameter(p.name).value for p in itf.PARAMETERS if node.has_parameter(p.name)}
    problems += [msg for p in itf.PARAMETERS if p.name in values and (msg := check_parameter(p, values[p.name]))]
    if problems:
        raise ConfigError("invalid parameters: " + "; ".join(problems))
    values = {p.name: coerce(p, v) for p, v in zip(itf.PARAMETERS, values.values())}
    unknown = sorted(name for name in overrides
                     if name not in itf.PARAMETER_BY_NAME and name not in ROS_OWN_PARAMETERS
                     and not name.startswith("qos_overrides."))
    if unknown:
        node.get_logger().warn(f"ignoring unknown parameter(s) {', '.join(unknown)}; cgp_sim's parameters "
                               f"are {', '.join(p.name for p in itf.PARAMETERS)}")
    return values


def _declare(node, overrides: Mapping) -> list[str]:
    """Declare every parameter; returns the problems with start-up values rclpy itself refuses, worded like
    :func:`check_parameter` (none expected: see below)."""
    problems = []
    for p in itf.PARAMETERS:
        # Declared with dynamic typing, and checked by check_parameter (at start-up and in the parameter
        # callback), so that a value of the wrong type gets a reason naming the parameter and the expected
        # type ("realtime must be bool, got str 'yes'") rather than rclpy's "Wrong parameter type, expected
        # '1' got '4'"; and `-p rate_hz:=60` (an integer to the ROS parser) is accepted and converted.
        # The type and range are stated in the descriptor for `ros2 param describe`.
        descriptor = ParameterDescriptor(
            name=p.name, type=ParameterType.PARAMETER_NOT_SET, description=p.description,
            additional_constraints=_constraints(p), read_only=p.read_only, dynamic_typing=True)
        try:
            node.declare_parameter(p.name, p.default, descriptor)
        except InvalidParameterTypeException:
            value = overrides[p.name].value
            problems.append(f"{p.name} must be {type(p.default).__name__}, got {type(value).__name__} "
                            f"{_brief(value)}")
    return problems


def refusal(parameters) -> str | None:
    """Why the node refuses this run-time change of ``parameters`` (rclpy ``Parameter`` objects; None if it
    takes them).  Parameters the node does not have are left to rclpy."""
    for param in parameters:
        spec = itf.PARAMETER_BY_NAME.get(param.name)
        if spec is not None and (problem := check_parameter(spec, param.value)):
            return problem
    return None


def _constraints(spec: itf.ParameterSpec) -> str:
    text = type(spec.default).__name__
    if spec.choices is not None:
        text += f", one of {', '.join(spec.choices)}"
    if spec.minimum is not None:
        text += f", >= {spec.minimum:g}"
    if spec.maximum is not None:
        text += f", <= {spec.maximum:g}"
    return text


def _brief(value, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[:limit] + "..."


def coerce(spec: itf.ParameterSpec, value):
    """``value`` as the node keeps it: a float parameter's value is a float."""
    return float(value) if isinstance(spec.default, float) else value


def check_parameter(spec: itf.ParameterSpec, value) -> str | None:
    """Why ``value`` is not acceptable for ``spec`` (None if it is)."""
    expected = type(spec.default)
    if expected is float and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    if not isinstance(value, expected) or (expected is int and isinstance(value, bool)):
        return f"{spec.name} must be {expected.__name__}, got {type(value).__name__} {_brief(value)}"
    if isinstance(value, float) and not math.isfinite(value):
        return f"{spec.name} must be finite, got {value}"
    if spec.choices is not None and value not in spec.choices:
        return f"{spec.name} must be one of {', '.join(spec.choices)}, got {_brief(value)}"
    if spec.pattern is not None and (not spec.pattern.fullmatch(value) or value.startswith("/")):
        return f"{spec.name} must be {spec.pattern_text}, got {_brief(value)}"
    if spec.minimum is not None and value < spec.minimum:
        return f"{spec.name} must be >= {spec.minimum:g}, got {value}"
    if spec.maximum is not None and value > spec.maximum:
        return f"{spec.name} must be <= {spec.maximum:g}, got {value}"
    return None
