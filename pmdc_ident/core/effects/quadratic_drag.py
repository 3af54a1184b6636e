"""``quadratic_drag``: a torque proportional to w|w| (fan, propeller, air)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pmdc_ident.core.effects import layout
from pmdc_ident.core.effects.base import (
    PEAK_TORQUE,
    DataScales,
    DetectionProbe,
    Effect,
    Ladder,
    MujocoContext,
    MujocoTerms,
    ParamSpec,
    RecordScales,
    SimPath,
)

__all__ = ["QuadraticDrag"]


@dataclass(frozen=True)
class QuadraticDrag(Effect):
    NAME: ClassVar[str] = "quadratic_drag"
    DESCRIPTION: ClassVar[str] = "torque proportional to w|w| (fan, propeller, air)"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "coeff_nm_s2": ParamSpec("N*m*s^2/rad^2", 0.0, 1e3, "quadratic drag coefficient"),
    }
    KERNEL_SLOTS = {"coeff_nm_s2": layout.CQ}
    SIM_PATH = SimPath.FAST
    FAST_COLUMNS = {"coeff_nm_s2": layout.COL_CQ}
    PRIOR = 50
    SEPARATING_TESTS = {
        "coulomb_friction": (
            "a staircase up to full speed: quadratic drag grows with speed squared"
        ),
        "load_torque": (
            "a staircase to full speed in both directions: drag grows with speed squared and "
            "changes sign, a load torque does neither"
        ),
    }
    REVEAL = "full_staircase"
    BENCHMARK_LADDER = Ladder("% rated torque at w0", (5.0, 10.0, 20.0, 40.0))
    MUJOCO_MAPPING = (
        'joint `damping="B N^2 Cq N^3"`: the quadratic term b of MuJoCo\'s polynomial '
        "damping -(a w + b w abs(w))"
    )

    coeff_nm_s2: float

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        t, w = sc.peak_torque_nm, sc.top_speed_rad_s
        return [
            DetectionProbe(
                lambda s: cls(s / w**2), 0.02 * t, "N*m at top speed", t, PEAK_TORQUE, 1, True
            )
        ]

    @classmethod
    def starts(cls, sc: DataScales) -> list[QuadraticDrag]:
        return [cls.clipped(sc.torque_nm * f / sc.speed_rad_s**2) for f in (0.1, 0.3, 1.0)]

    def mujoco_terms(self, ctx: MujocoContext) -> MujocoTerms:
        # the joint's second damping coefficient (MuJoCo >= 4), reflected through the gear
        return MujocoTerms(joint_damping2=self.coeff_nm_s2 * ctx.reduction**3)
