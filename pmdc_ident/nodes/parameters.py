"""Declaring a node's parameters from its table (:mod:`.parameter_tables`), one way.

:func:`declare` declares every entry with a descriptor (description, range, choices,
read-only unless the entry is ``runtime``), turns a bad override into one line
naming the parameter, and installs the node's one set-parameters callback, which
refuses a runtime change with a reason (the table's range and choices, then the
node's own ``check``, which may need what the start values set up, e.g. the motor).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.node import Node
from rclpy.parameter import Parameter

from pmdc_ident.core.errors import PmdcError
from pmdc_ident.process.parameter_tables import NodeParameter, ParameterTable

__all__ = ["declare", "descriptor"]

Check = Callable[[str, Any], str]  # (name, value) -> reason it is refused, '' if fine


def descriptor(p: NodeParameter) -> ParameterDescriptor:
    d = ParameterDescriptor(description=p.description, read_only=not p.runtime)
    if p.choices:
        d.additional_constraints = "one of: " + ", ".join(p.choices)
    if p.lower is None or p.upper is None or isinstance(p.default, bool):
        return d
    if isinstance(p.default, float):
        d.floating_point_range = [
            FloatingPointRange(from_value=float(p.lower), to_value=float(p.upper), step=0.0)
        ]
    elif isinstance(p.default, int):
        d.integer_range = [IntegerRange(from_value=int(p.lower), to_value=int(p.upper), step=1)]
    return d


def declare(node: Node, table: ParameterTable, check: Check | None = None) -> dict[str, Any]:
    """Declare ``table`` on ``node``; the values it starts with, each checked against
    the table (the node checks the start values that need more context itself).

    Raises :class:`PmdcError` (one line) for an override of the wrong type, out of
    range or not among the choices. ``check`` judges runtime changes.
    """
    for p in table:
        try:
            node.declare_parameter(p.name, p.default, descriptor(p))
        except Exception as exc:  # rclpy raises several types for a bad override
            text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            if "expecting type" in text:
                hint = " (write e.g. 1000.0)" if p.type_name == "float" else ""
                text = f"must be of type {p.type_name}{hint}"
            msg = f"parameter {p.name}: {text} ({p.description})"
            raise PmdcError(msg) from None
    values = {p.name: node.get_parameter(p.name).value for p in table}
    for p in table:
        reason = p.refusal(values[p.name])
        if reason:
            raise PmdcError(reason)

    def on_set(params: list[Parameter]) -> SetParametersResult:
        for q in params:
            spec = table[q.name] if q.name in table.names else None
            reason = spec.refusal(q.value) if spec is not None else ""
            reason = reason or (check(q.name, q.value) if check else "")
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(on_set)
    return values
