"""``cogging``: a torque periodic in the shaft angle."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from pmdc_ident.core.effects import layout
from pmdc_ident.core.effects.base import (
    PEAK_TORQUE,
    CandidateContext,
    DataScales,
    DetectionProbe,
    Effect,
    Ladder,
    MujocoContext,
    MujocoTerms,
    ParamSpec,
    RecordScales,
)

__all__ = ["Cogging"]


@dataclass(frozen=True)
class Cogging(Effect):
    NAME: ClassVar[str] = "cogging"
    DESCRIPTION: ClassVar[str] = "torque periodic in shaft angle"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "torque_nm": ParamSpec("N*m", 0.0, 1e4, "cogging torque amplitude"),
        "periods_per_rev": ParamSpec("1/rev", 1.0, 1000.0, "cogging periods per turn", False),
        "phase_rad": ParamSpec("rad", -10.0, 10.0, "cogging phase"),
    }
    KERNEL_SLOTS = {
        "torque_nm": layout.TCOG,
        "periods_per_rev": layout.NCOG,
        "phase_rad": layout.PHCOG,
    }
    PRIOR = 90
    FIT_IN_SHAFT_ANGLE = True
    SEPARATING_TESTS = {
        "coulomb_friction": "a slow run over several turns: cogging repeats with the shaft angle",
        "stribeck_friction": "a slow run over several turns: cogging repeats with the shaft angle",
    }
    REVEAL = "crawls"
    DETECTION_NOT_SHOWN = "the shaft turned too little or too fast"
    BENCHMARK_LADDER = Ladder("% rated torque", (3.0, 6.0, 12.0, 25.0))
    MUJOCO_MAPPING = (
        '`<dcmotor cogging="T N phi+pi">`: MuJoCo adds A sin(poles theta + phase) in the '
        "motor shaft's angle, the candidate's torque T sin(N theta + phi) opposes +w; N per "
        "motor turn (a real number: MuJoCo takes it as given)"
    )

    torque_nm: float
    periods_per_rev: float
    phase_rad: float = 0.0

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        t = sc.peak_torque_nm
        return [
            DetectionProbe(
                lambda s, n=n: cls(s, float(n), 0.0), 0.02 * t, "N*m", t, PEAK_TORQUE, 2, True
            )
            for n in sc.periods_per_turn
        ]

    @classmethod
    def detection_detail(cls, sc: RecordScales) -> str:
        periods = ", ".join(f"{n:g}" for n in sc.periods_per_turn)
        return f"largest over {periods} periods per turn"

    @classmethod
    def starts(cls, sc: DataScales) -> list[Cogging]:
        return [
            cls.clipped(sc.torque_nm * 0.1, float(n), ph)
            for n in sc.periods_per_rev
            for ph in (-2.5, -1.0, 0.5, 2.0)
        ]

    def mujoco_terms(self, ctx: MujocoContext) -> MujocoTerms:
        return MujocoTerms(
            cogging=(self.torque_nm, self.periods_per_rev, self.phase_rad + math.pi)
        )

    @classmethod
    def untestable(cls, ctx: CandidateContext) -> str:
        if not ctx.angle_periods:
            return "the shaft turned too little to show a period in its angle"
        return ""
