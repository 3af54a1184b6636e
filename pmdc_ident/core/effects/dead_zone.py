"""``dead_zone``: the driver ignores commands smaller than a threshold."""

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

__all__ = ["DeadZone"]


@dataclass(frozen=True)
class DeadZone(Effect):
    NAME: ClassVar[str] = "dead_zone"
    DESCRIPTION: ClassVar[str] = "driver ignores commands smaller than a threshold"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "voltage_v": ParamSpec("V", 0.0, 1000.0, "dead-zone half width"),
    }
    KERNEL_SLOTS = {"voltage_v": layout.V_DZ}  # applied to the command before the kernel
    LINEAR_BETWEEN_SAMPLES = True
    PRIOR = 70
    SEPARATING_TESTS = {
        "load_torque": (
            "compare a coast-down (no command, the load still acts) with a low-voltage staircase"
        ),
    }
    REVEAL = "low_voltage"
    BENCHMARK_LADDER = Ladder("% rated voltage", (1.0, 2.0, 4.0, 8.0))
    MUJOCO_NOT_CARRIED = "driver dead zone (put it in your controller's output stage)"

    voltage_v: float

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        v = sc.peak_voltage_v
        return [DetectionProbe(cls, 0.01 * v, "V", v, "the largest command", 1, False)]

    @classmethod
    def starts(cls, sc: DataScales) -> list[DeadZone]:
        return [cls.clipped(sc.voltage_v * f) for f in (0.01, 0.02, 0.035, 0.05, 0.075, 0.1)]
