"""``inductance_saturation``: L falls at high current."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from pmdc_ident.core.effects import layout
from pmdc_ident.core.effects.base import (
    CandidateContext,
    DataScales,
    DetectionProbe,
    Effect,
    Ladder,
    ParamSpec,
    RecordScales,
    SimPath,
)

__all__ = ["InductanceSaturation"]


@dataclass(frozen=True)
class InductanceSaturation(Effect):
    NAME: ClassVar[str] = "inductance_saturation"
    DESCRIPTION: ClassVar[str] = "L falls at high current: L(i) = L / (1 + (i/I_sat)^2)"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "saturation_current_a": ParamSpec("A", 1e-3, 1e5, "current where L has halved"),
    }
    KERNEL_SLOTS = {"saturation_current_a": layout.ISAT}
    SIM_PATH = SimPath.REDISCRETISED
    PRIOR = 110
    SEPARATING_TESTS = {
        "brush_drop": (
            "steps to a low and a high current, sampled at >= 10 samples per L/R: saturation "
            "speeds up only the high-current rise"
        ),
    }
    REVEAL = "current_range"
    BENCHMARK_LADDER = Ladder("% fall of L at peak current", (20.0, 35.0, 50.0, 70.0))
    MUJOCO_NOT_CARRIED = "inductance falling with current (MuJoCo's L is constant)"

    saturation_current_a: float

    def varies_within_sample(self) -> bool:
        return self.saturation_current_a > 0.0

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        i = sc.peak_current_a

        def make(s: float) -> InductanceSaturation:
            return cls(i * math.sqrt((1.0 - min(s, 0.99)) / max(s, 1e-9)))

        fall = "fall of L at the largest current"
        return [DetectionProbe(make, 0.2, fall, 1.0, "L", 1, False, largest=0.99)]

    @classmethod
    def starts(cls, sc: DataScales) -> list[InductanceSaturation]:
        return [cls.clipped(max(sc.current_a * f, 1e-3)) for f in (0.5, 1.0, 2.0)]

    @classmethod
    def untestable(cls, ctx: CandidateContext) -> str:
        return "L is held (the data do not resolve L/R)" if ctx.inductance_held else ""
