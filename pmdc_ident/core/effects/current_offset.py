"""``current_offset``: the current sensor reads non-zero at zero current."""

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
    SimPath,
)

__all__ = ["CurrentOffset"]


@dataclass(frozen=True)
class CurrentOffset(Effect):
    NAME: ClassVar[str] = "current_offset"
    DESCRIPTION: ClassVar[str] = "current sensor reads non-zero at zero current"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "offset_a": ParamSpec("A", -1e3, 1e3, "current sensor offset"),
    }
    KERNEL_SLOTS = {"offset_a": layout.I_OFF}  # added to the measured current
    LINEAR_BETWEEN_SAMPLES = True
    SIM_PATH = SimPath.FAST
    FAST_COLUMNS = {"offset_a": layout.COL_MEASURED_CURRENT}
    PRIOR = 80
    SEPARATING_TESTS = {
        "brush_drop": "read the current with the armature open: an offset reads non-zero",
        "dead_zone": "read the current with the armature open: an offset reads non-zero",
    }
    REVEAL = "open_rest"
    BENCHMARK_LADDER = Ladder("% rated current", (1.0, 2.0, 4.0, 8.0))
    MUJOCO_NOT_CARRIED = "current-sensor offset (a measurement effect, not dynamics)"

    offset_a: float

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        i = sc.peak_current_a
        return [DetectionProbe(cls, 0.01 * i, "A", i, "the largest current", 1, True)]

    @classmethod
    def starts(cls, sc: DataScales) -> list[CurrentOffset]:
        return [cls.clipped(sc.current_a * f) for f in (-0.05, -0.01, 0.01, 0.05)]
