"""``coulomb_friction``: a torque opposing motion, constant in size (with stiction)."""

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

__all__ = ["CoulombFriction"]


@dataclass(frozen=True)
class CoulombFriction(Effect):
    NAME: ClassVar[str] = "coulomb_friction"
    DESCRIPTION: ClassVar[str] = "torque opposing motion, constant in size"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "torque_nm": ParamSpec("N*m", 0.0, 1e4, "Coulomb friction torque"),
    }
    KERNEL_SLOTS = {"torque_nm": layout.TC}
    SIM_PATH = SimPath.FAST
    FAST_COLUMNS = {"torque_nm": layout.COL_TC}
    PRIOR = 10
    SEPARATING_TESTS = {
        "load_torque": (
            "run the motor in reverse (steps or a staircase with negative voltage): Coulomb "
            "friction changes sign with the direction, a load torque does not"
        ),
        "stribeck_friction": (
            "run a slow staircase near zero speed: Stribeck friction falls off with speed"
        ),
        "brush_drop": (
            "compare a coast-down (open armature, no brush drop) with a powered staircase"
        ),
        "dead_zone": (
            "compare a coast-down (no command) with a powered staircase, or measure the "
            "terminal voltage"
        ),
        "current_offset": "read the current with the armature open: an offset reads non-zero",
    }
    REVEAL = "slow_both_ways"
    BENCHMARK_LADDER = Ladder("% rated torque", (3.0, 6.0, 12.0, 25.0))
    MUJOCO_MAPPING = (
        "joint `frictionloss` = Tc N (MuJoCo's dry-friction constraint, made stiff: "
        "`solreffriction` two steps); beside a Stribeck term, the Coulomb level Fc of "
        "`<dcmotor lugre>`"
    )

    torque_nm: float

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        t = sc.peak_torque_nm
        return [DetectionProbe(cls, 0.02 * t, "N*m", t, PEAK_TORQUE, 1, True)]

    @classmethod
    def starts(cls, sc: DataScales) -> list[CoulombFriction]:
        return [cls.clipped(sc.torque_nm * f) for f in (0.03, 0.1, 0.3)]

    def mujoco_terms(self, ctx: MujocoContext) -> MujocoTerms:
        return MujocoTerms(coulomb_nm=self.torque_nm)
