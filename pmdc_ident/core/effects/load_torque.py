"""``load_torque``: a constant torque, direction-independent (e.g. a hanging mass)."""

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

__all__ = ["LoadTorque"]


@dataclass(frozen=True)
class LoadTorque(Effect):
    NAME: ClassVar[str] = "load_torque"
    DESCRIPTION: ClassVar[str] = "constant torque, direction-independent (e.g. a hanging mass)"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "torque_nm": ParamSpec("N*m", -1e4, 1e4, "load torque (positive opposes +w)"),
    }
    KERNEL_SLOTS = {"torque_nm": layout.TL}
    # a constant torque leaves the motor linear over each sample
    LINEAR_BETWEEN_SAMPLES = True
    SIM_PATH = SimPath.FAST
    FAST_COLUMNS = {"torque_nm": layout.COL_TL}
    PRIOR = 30
    SEPARATING_TESTS = {
        "current_offset": "read the current with the armature open: an offset reads non-zero",
    }
    REVEAL = "slow_both_ways"
    BENCHMARK_LADDER = Ladder("% rated torque", (3.0, 6.0, 12.0, 25.0))
    MUJOCO_MAPPING = (
        'a passive `<dcmotor input="none" motorconst="0 0">` on the joint whose '
        'zero-pole cogging is the constant torque, `cogging="TL 0 -1.5708"` (remove it '
        "where your scene models the load itself)"
    )

    torque_nm: float

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        t = sc.peak_torque_nm
        return [DetectionProbe(cls, 0.02 * t, "N*m", t, PEAK_TORQUE, 1, True)]

    @classmethod
    def starts(cls, sc: DataScales) -> list[LoadTorque]:
        return [cls.clipped(sc.torque_nm * f) for f in (-0.2, -0.05, 0.05, 0.2)]

    def mujoco_terms(self, ctx: MujocoContext) -> MujocoTerms:
        return MujocoTerms(constant_torque_nm=self.torque_nm)
