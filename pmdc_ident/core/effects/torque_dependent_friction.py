"""``torque_dependent_friction``: friction that grows with the torque the motor delivers.

A gearbox loses a share of the torque it transmits in its meshes (its efficiency), a
lead screw or a worm more, a loaded bearing some: a friction torque ``mu |Kt i|``
against the motion, on top of whatever friction is constant. Against a constant
(Coulomb) friction it shows in a staircase: the current at constant speed grows in
proportion to the torque (no intercept at zero speed from it). While the motor only
drives, ``Kt (1 - mu) i`` is a smaller torque constant, which the scale ambiguity of
(Kt, J, B) absorbs; it is told apart where the motor brakes (a step down, a reversal,
the chirp): the friction then adds to the braking torque, ``Kt (1 + mu) i``, and in a
coast-down (no current) it vanishes.

Held over each sub-step at the sub-step's current, as the kernel holds every torque;
at rest it adds ``mu |Kt i|`` to what static friction can hold (alone it never holds
the rotor: ``mu`` < 1).

An opt-in candidate (``diagnose --effects ...,torque_dependent_friction``): it is not
in the benchmark's vocabulary, so the default diagnosis does not try it (see
docs/adding-an-effect.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pmdc_ident.core.effects import layout
from pmdc_ident.core.effects.base import (
    DataScales,
    DetectionProbe,
    Effect,
    ParamSpec,
    RecordScales,
)

__all__ = ["TorqueDependentFriction"]


@dataclass(frozen=True)
class TorqueDependentFriction(Effect):
    NAME: ClassVar[str] = "torque_dependent_friction"
    DESCRIPTION: ClassVar[str] = (
        "friction torque mu |Kt i| against the motion, growing with the torque the motor "
        "delivers (a gearbox's or lead screw's mesh losses)"
    )
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "loss_ratio": ParamSpec("1", 0.0, 0.9, "share mu of the motor torque lost to friction"),
    }
    KERNEL_SLOTS = {"loss_ratio": layout.MU}
    DEFAULT_CANDIDATE = False
    PRIOR = 55  # after the friction and drag of every motor, before the drive's effects
    REVEAL = "current_range"
    SEPARATING_TESTS = {
        "coulomb_friction": (
            "a staircase under several loads (or both directions at several speeds): Coulomb "
            "friction is the same at every torque, a torque-dependent friction grows with "
            "the current"
        ),
        "load_torque": (
            "run in reverse: a load torque keeps its sign, a torque-dependent friction opposes "
            "the motion both ways"
        ),
        "quadratic_drag": (
            "a coast-down from full speed: drag still acts without current, a "
            "torque-dependent friction does not"
        ),
        "stribeck_friction": (
            "a slow staircase near zero speed: Stribeck friction is largest there, a "
            "torque-dependent friction follows the current"
        ),
        "brush_drop": (
            "measure the terminal voltage, or compare a coast-down with a powered staircase: "
            "a brush drop takes voltage, a torque-dependent friction takes torque"
        ),
    }
    MUJOCO_NOT_CARRIED = (
        "friction proportional to the transmitted torque (MuJoCo's frictionloss is constant)"
    )

    loss_ratio: float

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        return [DetectionProbe(cls, 0.02, "of the motor torque", 1.0, "the motor torque", 1, True)]

    @classmethod
    def starts(cls, sc: DataScales) -> list[TorqueDependentFriction]:
        return [cls.clipped(mu) for mu in (0.03, 0.1, 0.25, 0.5)]
