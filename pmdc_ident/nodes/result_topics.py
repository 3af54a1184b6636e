"""The results' numbers as plottable arrays, one topic per quantity (ROS-free).

The JSON documents (``identified_parameters``, ``model_drift``) stay the full record;
beside them each number a plotting tool needs gets a ``std_msgs/Float64MultiArray``
topic of its own, with one labelled dimension that says what each element is and in
which unit (``R [ohm]: value,ci95_low,ci95_high,stderr,identifiable``):

* ``identified_parameters/<name>`` (latched, one per identified parameter; an effect
  parameter ``coulomb_friction.torque_nm`` on ``identified_parameters/coulomb_friction/
  torque_nm``): :data:`PARAMETER_FIELDS`, ``identifiable`` 1 or 0, NaN where the JSON
  has ``null`` (no interval);
* ``model_drift/<quantity>`` (every report: ``resistance``, ``back_emf``, ``friction``,
  ``delay``, ``temperature_rise``): :data:`DRIFT_FIELDS`, the level 0 OK, 1 WARN,
  2 ERROR (the temperature rise carries the resistance's level; its identified value
  is 0 K).

``rqt_plot /identified_parameters/R/data[0]`` or PlotJuggler plot them as they are;
the layout makes ``ros2 topic echo`` readable. This module builds the names, labels
and values (:func:`parameter_topics`, :func:`drift_topics`, plain Python) and the
message (:func:`array_message`); the nodes publish them.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from std_msgs.msg import Float64MultiArray, MultiArrayDimension

if TYPE_CHECKING:
    from pmdc_ident.node_logic.drift_monitor import DriftReport

__all__ = [
    "DRIFT_FIELDS",
    "DRIFT_PREFIX",
    "PARAMETER_FIELDS",
    "PARAMETER_PREFIX",
    "NumericTopic",
    "array_message",
    "drift_topics",
    "parameter_topics",
    "topic_token",
]

PARAMETER_PREFIX = "identified_parameters"
DRIFT_PREFIX = "model_drift"
PARAMETER_FIELDS = ("value", "ci95_low", "ci95_high", "stderr", "identifiable")
DRIFT_FIELDS = ("estimate", "ci95_low", "ci95_high", "identified", "level")


@dataclass(frozen=True)
class NumericTopic:
    """One quantity's array: relative topic name, layout label and the numbers."""

    topic: str
    label: str
    values: tuple[float, ...]


def topic_token(name: str) -> str:
    """A parameter or quantity name as (part of) a ROS topic name: ``.`` nests
    (``coulomb_friction/torque_nm``), other characters a name may not hold become
    ``_``, and a part starting with a digit gets a leading ``_``."""
    parts = []
    for part in name.split("."):
        token = re.sub(r"[^A-Za-z0-9_]", "_", part) or "_"
        parts.append("_" + token if token[0].isdigit() else token)
    return "/".join(parts)


def _label(name: str, unit: str, fields: tuple[str, ...]) -> str:
    return f"{name} [{unit}]: {','.join(fields)}"


def _num(x: Any) -> float:
    return math.nan if x is None else float(x)


def parameter_topics(doc: Mapping[str, Any]) -> list[NumericTopic]:
    """One array per parameter of an identification result document."""
    out = []
    for name, p in doc.get("parameters", {}).items():
        lo, hi = p.get("ci95") or (None, None)
        values = (
            _num(p.get("value")),
            _num(lo),
            _num(hi),
            _num(p.get("stderr")),
            1.0 if p.get("identifiable") else 0.0,
        )
        label = _label(name, str(p.get("unit", "")), PARAMETER_FIELDS)
        out.append(NumericTopic(f"{PARAMETER_PREFIX}/{topic_token(name)}", label, values))
    return out


def drift_topics(report: DriftReport) -> list[NumericTopic]:
    """One array per monitored quantity of a drift report, and the temperature rise."""
    out = []
    for q in report.quantities:
        values = (q.value, q.value - q.ci95, q.value + q.ci95, q.reference, float(q.level))
        label = _label(q.name, q.unit, DRIFT_FIELDS)
        out.append(NumericTopic(f"{DRIFT_PREFIX}/{topic_token(q.name)}", label, values))
    r = report.quantity("resistance")
    dt, ci = report.temperature_rise_k, report.temperature_ci95_k
    out.append(
        NumericTopic(
            f"{DRIFT_PREFIX}/temperature_rise",
            _label("temperature_rise", "K", DRIFT_FIELDS),
            (dt, dt - ci, dt + ci, 0.0, float(r.level)),
        )
    )
    return out


def array_message(topic: NumericTopic) -> Float64MultiArray:
    """A :class:`NumericTopic` as a ``Float64MultiArray`` with its labelled layout."""
    msg = Float64MultiArray(data=[float(x) for x in topic.values])
    n = len(topic.values)
    msg.layout.dim = [MultiArrayDimension(label=topic.label, size=n, stride=n)]
    return msg
