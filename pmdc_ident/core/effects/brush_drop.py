"""``brush_drop``: a voltage drop across the brushes with the sign of the current."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pmdc_ident.core.effects import layout
from pmdc_ident.core.effects.base import (
    DataScales,
    DetectionProbe,
    Effect,
    Ladder,
    ParamSpec,
    RecordScales,
)

__all__ = ["BrushDrop"]


@dataclass(frozen=True)
class BrushDrop(Effect):
    NAME: ClassVar[str] = "brush_drop"
    DESCRIPTION: ClassVar[str] = (
        "voltage drop across the brushes with the sign of current: Vb tanh(i/i_knee), "
        "the hard sign at i_knee = 0"
    )
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "voltage_v": ParamSpec("V", 0.0, 100.0, "total brush voltage drop"),
        # a contact film conducts like a resistor at small current (slope Vb/i_knee)
        # and saturates at Vb above a few i_knee; 0 is the limit of a hard sign
        "knee_current_a": ParamSpec(
            "A", 0.0, 1e4, "current where the drop reaches 76 % of Vb", limit=0.0
        ),
    }
    KERNEL_SLOTS = {"voltage_v": layout.VB, "knee_current_a": layout.IB}
    PRIOR = 20
    # the hard sign first, then a contact film's smooth drop with its knee
    SECOND_FORM = "knee_current_a"
    SEPARATING_TESTS = {
        "dead_zone": (
            "measure the terminal voltage, or run a low-voltage staircase and a sweep that "
            "reverses current: a dead zone acts on the command, a brush drop on the current"
        ),
        "load_torque": (
            "compare a coast-down (open armature: no brush drop, the load still acts) with a "
            "powered staircase"
        ),
    }
    REVEAL = "low_voltage"
    BENCHMARK_LADDER = Ladder("% rated voltage", (1.0, 2.0, 4.0, 8.0))
    MUJOCO_NOT_CARRIED = "brush voltage drop (no such term in MuJoCo's motor)"

    voltage_v: float
    knee_current_a: float = 0.0  # the hard sign: a dead band on the driving voltage

    def varies_within_sample(self) -> bool:
        # a smooth drop's slope is a resistance that changes with the current
        return self.voltage_v > 0.0 and self.knee_current_a > 0.0

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        v = sc.peak_voltage_v
        return [DetectionProbe(cls, 0.01 * v, "V", v, "the largest command", 1, False)]

    @classmethod
    def starts(cls, sc: DataScales) -> list[BrushDrop]:
        # the hard sign (knee 0), then a contact film's knee at a share of the current
        v = sc.voltage_v
        hard = [cls.clipped(v * f, 0.0) for f in (0.01, 0.02, 0.035, 0.05, 0.075, 0.1)]
        return hard + [
            cls.clipped(v * f, sc.current_a * g)
            for f in (0.02, 0.05, 0.1)
            for g in (0.03, 0.1, 0.3)
        ]
