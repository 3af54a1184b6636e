"""``delay``: the command reaches the motor late (transport delay, then a lag)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from pmdc_ident.core.effects import layout
from pmdc_ident.core.effects.base import (
    DataScales,
    DetectionProbe,
    Effect,
    Ladder,
    MujocoContext,
    MujocoTerms,
    ParamSpec,
    RecordScales,
)

__all__ = ["Delay"]


@dataclass(frozen=True)
class Delay(Effect):
    NAME: ClassVar[str] = "delay"
    DESCRIPTION: ClassVar[str] = (
        "command reaches the motor late: a transport delay, then a first-order lag"
    )
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "delay_s": ParamSpec("s", 0.0, 1.0, "transport delay"),
        # a drive's output filter or current loop: tau dVa/dt = V - Va; 0 is the limit of
        # a pure transport delay
        "lag_s": ParamSpec("s", 0.0, 1.0, "first-order lag time constant", limit=0.0),
    }
    # applied to the command before the kernel
    KERNEL_SLOTS = {"delay_s": layout.DELAY, "lag_s": layout.LAG}
    LINEAR_BETWEEN_SAMPLES = True
    PRIOR = 60
    # a transport delay first, then one followed by a first-order lag
    SECOND_FORM = "lag_s"
    # when L/R is near the sample period the linear fit places L to mimic a delay
    L_SCAN = (1 / 3, 1 / 10, 1 / 30)
    SEPARATING_TESTS = {
        "inductance_saturation": (
            "sample faster (>= 10 samples per L/R) and step at low and high current"
        ),
        "dead_zone": (
            "a small sweep around a held offset and a large step: a delay shifts both in time, "
            "a dead zone removes only small commands"
        ),
        "current_offset": (
            "read the current with the armature open: an offset reads non-zero, a delay does not"
        ),
    }
    REVEAL = "sharp_steps"
    BENCHMARK_LADDER = Ladder("samples", (0.5, 1.0, 2.0, 4.0))
    MUJOCO_MAPPING = (
        '`<dcmotor delay="d" nsample="ceil(d/step)+2">`: MuJoCo reads the command from '
        "its own history, d late (zero-order hold); a drive's first-order lag (lag_s) as a "
        "drive joint whose speed is the lagged voltage (armature lag_s D, damping D, driven "
        "by a `<general>` actuator of gain D that takes the command and the delay), the "
        "motor on a fixed tendon of the motor shaft's angle minus the drive joint's over K "
        '(`input="none"`: its back-EMF K (w - V_lag/K) is the lagged voltage minus the '
        "motor's), its friction and cogging on passive elements of the joint; D = 1e6 / R "
        "leaves a voltage error of 1e-6 R i"
    )

    delay_s: float
    lag_s: float = 0.0

    def mujoco_terms(self, ctx: MujocoContext) -> MujocoTerms:
        return MujocoTerms(delay_s=self.delay_s, lag_s=self.lag_s)

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        return [DetectionProbe(cls, 0.5 * sc.dt_s, "s", sc.dt_s, "one sample", 1, False)]

    @classmethod
    def detection_floor(cls, sc: RecordScales) -> float:
        """A delay under 1/pi sample reads as the signal chain's lag: never named."""
        return sc.dt_s / math.pi

    @classmethod
    def starts(cls, sc: DataScales) -> list[Delay]:
        # every whole sample: at high sweep frequencies the cost wraps with the phase;
        # then a first-order lag behind a short transport delay (a drive's output filter)
        transport = [cls.clipped(min(k * sc.dt_s, 1.0), 0.0) for k in (*range(1, 25), 30, 40)]
        return transport + [
            cls.clipped(d * sc.dt_s, min(k * sc.dt_s, 1.0))
            for d in (0.0, 1.0)
            for k in (0.5, 1, 2, 4, 8, 16)
        ]
