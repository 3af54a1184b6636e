"""The contract every effect of the vocabulary fulfils: :class:`Effect` and its hooks.

An effect is a frozen dataclass whose fields are its physical parameters (units in the
names, ranges in :attr:`Effect.SPECS`). Its class also declares everything the rest of
the package needs to know about it, so that the model, the fits, the diagnosis, the
benchmark and the exports loop over the registry (:data:`~pmdc_ident.core.effects.
EFFECT_TYPES`) instead of naming effects:

==========================  ===========================================================
hook                        read by
==========================  ===========================================================
``KERNEL_SLOTS``,           :func:`~pmdc_ident.core.model.effect_coefficients`: the
``KERNEL_NEUTRAL``,         slots of the coefficient vector the kernels read (named in
``write_coefficients``      :mod:`.layout`), the value a slot holds without the effect
``LINEAR_BETWEEN_SAMPLES``  :func:`~pmdc_ident.core.model.substeps_for`: one exact step
                            per sample suffices (no sub-steps)
``varies_within_sample``    the kernel re-discretises every sub-step (R or L change)
``SIM_PATH``,               the output-error fit: the fast kernel with analytic
``FAST_COLUMNS``            sensitivities, or ``simulate`` with finite differences
``DEFAULT_CANDIDATE``       the diagnosis tries it unless asked for a list
``starts``, ``L_SCAN``      the diagnosis' coarse scan: starting values sized from the
                            data (:class:`DataScales`), the inductances scanned with them
``SECOND_FORM``,            fitted first in its one-parameter limit, then with this
``FURTHER_FORM``            field free; a further field freed only where it helps
``SETTING_SCAN``            a setting fitted once per value (the closer one stands)
``FIT_IN_SHAFT_ANGLE``      fitted in the measured shaft angle (cogging)
``untestable``              why these data cannot test it (:class:`CandidateContext`)
``PRIOR``                   the tie order: more common in brushed PMDC motors first
``SEPARATING_TESTS``        per neighbour it can be confused with, the test that tells
                            the two apart (a pair is declared by one of the two)
``REVEAL``                  the plan's recipe of segments that make it visible
                            (:mod:`pmdc_ident.core.design.reveal`, ``plan --reveal``)
``detection_probes``,       the diagnosis' detection limit (:mod:`pmdc_ident.core.
``detection_floor``,        diagnosis.detection`): the effect at a size in a user's unit
``detection_detail``,       sized from the record (:class:`RecordScales`), the smallest
``DETECTION_NOT_SHOWN``     size worth naming, what the limit is the largest over, why
                            a record without probes cannot show it
``BENCHMARK_LADDER``        the benchmark's graded sizes in a user's unit (None: not in
                            the benchmark's vocabulary)
``mujoco_terms``,           the MuJoCo export: what it becomes in MJCF (joint terms,
``MUJOCO_MAPPING``,         ``<dcmotor>`` attributes, a passive actuator), the mapping
``MUJOCO_NOT_CARRIED``      in words (docs/mujoco.md), or why MuJoCo cannot carry it
==========================  ===========================================================

``test/core/test_effect_contract.py`` checks that every registered effect provides
every hook, consistently (and that its kernel lines exist: the simulation changes with
it). docs/adding-an-effect.md walks through adding one.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, MutableSequence
from dataclasses import asdict, dataclass, fields
from enum import Enum
from typing import ClassVar, TypeVar

from pmdc_ident.core.errors import ParameterError

__all__ = [
    "PEAK_TORQUE",
    "CandidateContext",
    "DataScales",
    "DetectionProbe",
    "Effect",
    "Ladder",
    "MujocoContext",
    "MujocoTerms",
    "ParamSpec",
    "RecordScales",
    "SimPath",
]

_E = TypeVar("_E", bound="Effect")


@dataclass(frozen=True)
class ParamSpec:
    """Unit, physical range and a typical size of one effect parameter."""

    unit: str
    lower: float
    upper: float
    description: str
    fitted: bool = True
    # the value at which the effect is its one-parameter limit (the heat integral, the
    # hard brush drop): a fit holds the field there unless asked to free it
    limit: float | None = None


@dataclass(frozen=True)
class DataScales:
    """Sizes read off the data, used to place starting values of effects."""

    torque_nm: float  # Kt * RMS current
    voltage_v: float  # largest |command|
    speed_rad_s: float  # largest |speed|
    current_a: float  # largest |current|
    dt_s: float  # median sample period
    charge_a2s: float  # int i^2 dt over all segments
    span_s: float  # from the first segment's start to the last one's end
    periods_per_rev: tuple[float, ...]  # shaft-angle harmonics to try for cogging


@dataclass(frozen=True)
class CandidateContext:
    """What the diagnosis knows of the data before it fits a candidate."""

    angle_periods: tuple[float, ...]  # periods per turn the residuals' angle spectrum shows
    inductance_held: bool  # L is held: the data do not resolve L/R


PEAK_TORQUE = "the peak motor torque on the record"  # what torque limits are relative to


@dataclass(frozen=True)
class RecordScales:
    """A record's own sizes, which an effect's detection probes are sized against
    (:mod:`pmdc_ident.core.diagnosis.detection`)."""

    peak_torque_nm: float  # Kt * the largest |current|
    peak_voltage_v: float  # the largest |command|
    peak_current_a: float
    top_speed_rad_s: float
    heat_a2s: float  # int i^2 dt while the armature is closed
    dt_s: float  # median sample period
    periods_per_turn: tuple[float, ...] = ()  # cogging periods the record resolves


@dataclass(frozen=True)
class DetectionProbe:
    """How the detection limit sizes an effect: the effect at size ``s`` (in
    ``unit``), a first size to try, the record's scale the limit is reported against
    (and its name), its parameter count, whether its signature grows in proportion to
    the size (to first order)."""

    make: Callable[[float], Effect]
    first: float
    unit: str
    scale: float
    relative_to: str
    n_params: int
    linear: bool
    largest: float | None = None  # the largest size to try (None: 10x ``scale``)


@dataclass(frozen=True)
class Ladder:
    """The benchmark's graded sizes of an effect, in a user's unit."""

    unit: str
    sizes: tuple[float, ...]


@dataclass(frozen=True)
class MujocoContext:
    """What an effect's MuJoCo terms are sized against (``exports.mujoco_xml``). The
    motor file's effects act at the motor shaft; the MJCF's joint is behind a gear of
    ``reduction`` motor turns per joint turn, and ``<dcmotor>`` works in the motor
    shaft's angle, speed and torque (its ``gear`` is the reduction)."""

    reduction: float
    resistance_ohm: float  # the export's winding resistance (in MuJoCo's current units)
    current_scale: float  # MuJoCo's current per real ampere (Kt/Ke: its one K is Ke)


@dataclass(frozen=True)
class MujocoTerms:
    """What an effect becomes in MJCF; zeros leave a term out. Torques, angles and
    speeds at the motor shaft unless the name says joint."""

    coulomb_nm: float = 0.0  # a dry friction (joint frictionloss, or LuGre's Coulomb level)
    joint_damping2: float = 0.0  # the joint's quadratic damping coefficient (at the joint)
    stribeck: tuple[float, float] = (0.0, 0.0)  # extra breakaway torque, Stribeck speed
    # further Gaussian falls (torque, speed) beside ``stribeck``, each a passive element
    stribeck_more: tuple[tuple[float, float], ...] = ()
    cogging: tuple[float, float, float] = (0.0, 0.0, 0.0)  # amplitude, poles, phase
    thermal: tuple[float, float, float] = (0.0, 0.0, 0.0)  # R_th K/W, C J/K, tempcoef 1/K
    delay_s: float = 0.0  # the actuator's command delay
    lag_s: float = 0.0  # a first-order lag of the voltage in front of the winding
    constant_torque_nm: float = 0.0  # against +w (a passive dcmotor's zero-pole cogging)
    partial: str = ""  # what of the effect the terms leave out ("": nothing)

    def carries_anything(self) -> bool:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name != "partial" and (any(v) if isinstance(v, tuple) else bool(v)):
                return True
        return False


class SimPath(Enum):
    """How the output-error fit simulates a model with the effect (the slowest wins)."""

    FAST = 2  # the fast kernel: one exact step per sample, analytic sensitivities
    SUBSTEPS = 1  # core.model.simulate with sub-steps, finite-difference Jacobian
    REDISCRETISED = 0  # ... re-discretised every sub-step (R or L vary): the slowest


@dataclass(frozen=True)
class Effect:
    """Base class. Subclasses set NAME, DESCRIPTION and SPECS (one entry per field) and
    the hooks of the module table; the defaults below fit an effect that adds a torque
    or a voltage the kernel reads from its slots."""

    NAME: ClassVar[str] = ""
    DESCRIPTION: ClassVar[str] = ""
    SPECS: ClassVar[dict[str, ParamSpec]] = {}

    # -- simulation (core.model, the output-error fit) ---------------------------------
    KERNEL_SLOTS: ClassVar[Mapping[str, int]] = {}  # field -> slot (core.effects.layout)
    KERNEL_NEUTRAL: ClassVar[Mapping[int, float]] = {}  # slot -> value without the effect
    LINEAR_BETWEEN_SAMPLES: ClassVar[bool] = False
    SIM_PATH: ClassVar[SimPath] = SimPath.SUBSTEPS
    FAST_COLUMNS: ClassVar[Mapping[str, int]] = {}  # fitted field -> layout.COL_*

    # -- diagnosis ------------------------------------------------------------------------
    DEFAULT_CANDIDATE: ClassVar[bool] = True
    PRIOR: ClassVar[int] = 1000
    SECOND_FORM: ClassVar[str | None] = None
    FURTHER_FORM: ClassVar[tuple[str, float] | None] = None  # (field, where it starts)
    SETTING_SCAN: ClassVar[tuple[str, tuple[float, ...]] | None] = None
    FIT_IN_SHAFT_ANGLE: ClassVar[bool] = False
    L_SCAN: ClassVar[tuple[float, ...]] = (1 / 3, 3.0)  # factors on L scanned with starts
    SEPARATING_TESTS: ClassVar[Mapping[str, str]] = {}

    # -- experiment design, detection limits ---------------------------------------------
    REVEAL: ClassVar[str] = ""  # the recipe key in core.design.reveal.RECIPES
    DETECTION_NOT_SHOWN: ClassVar[str] = ""  # why no probe fits a record ("": one always)

    # -- benchmark, exports ---------------------------------------------------------------
    BENCHMARK_LADDER: ClassVar[Ladder | None] = None
    MUJOCO_MAPPING: ClassVar[str] = ""  # how it is carried, in words ("": not carried)
    MUJOCO_NOT_CARRIED: ClassVar[str] = ""  # why MuJoCo cannot carry it ("": mujoco_terms)

    def __post_init__(self) -> None:
        for f in fields(self):
            spec = self.SPECS[f.name]
            raw = getattr(self, f.name)
            try:
                value = float(raw)
            except (TypeError, ValueError):
                msg = f"{self.NAME}.{f.name} must be a number, got {raw!r}"
                raise ParameterError(msg) from None
            if not (math.isfinite(value) and spec.lower <= value <= spec.upper):
                msg = (
                    f"{self.NAME}.{f.name} ({spec.description}) must lie in "
                    f"[{spec.lower:g}, {spec.upper:g}] {spec.unit}, got {value:g}"
                )
                raise ParameterError(msg)
            object.__setattr__(self, f.name, value)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def fitted_names(cls) -> tuple[str, ...]:
        return tuple(n for n, s in cls.SPECS.items() if s.fitted)

    def free_names(self) -> tuple[str, ...]:
        """The fields a fit estimates by default: the fitted ones but those held at
        their one-parameter limit (:attr:`ParamSpec.limit`)."""
        return tuple(
            n
            for n in self.fitted_names()
            if self.SPECS[n].limit is None or getattr(self, n) != self.SPECS[n].limit
        )

    # -- simulation hooks -------------------------------------------------------------------
    def write_coefficients(self, c: MutableSequence[float]) -> None:
        """Write this effect's numbers into the kernels' coefficient vector ``c``."""
        for name, slot in self.KERNEL_SLOTS.items():
            c[slot] = getattr(self, name)

    def varies_within_sample(self) -> bool:
        """Whether the electrical step changes within a sample (R heats, L saturates, a
        smooth brush drop's slope), so the kernel re-discretises every sub-step."""
        return False

    # -- diagnosis hooks ----------------------------------------------------------------------
    @classmethod
    def starts(cls: type[_E], sc: DataScales) -> list[_E]:
        """Starting values the diagnosis scans, sized from the data (within range)."""
        raise NotImplementedError

    @classmethod
    def untestable(cls, ctx: CandidateContext) -> str:
        """Why these data cannot test the effect ("": they can)."""
        return ""

    @classmethod
    def clipped(cls: type[_E], *values: float) -> _E:
        """``cls(*values)`` with each value moved into its physical range: a start sized
        from data in odd units must still be a valid effect, not an error."""
        specs = list(cls.SPECS.values())
        return cls(
            *(min(max(float(v), sp.lower), sp.upper) for v, sp in zip(values, specs, strict=True))
        )

    # -- detection hooks -------------------------------------------------------------------
    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        """The sizes the detection limit scans, in a user's unit (the limit is the
        largest over several probes; none: :attr:`DETECTION_NOT_SHOWN`)."""
        raise NotImplementedError

    @classmethod
    def detection_floor(cls, sc: RecordScales) -> float:
        """The smallest size the diagnosis would name (a limit is never below it)."""
        return 0.0

    @classmethod
    def detection_detail(cls, sc: RecordScales) -> str:
        """What a limit over several probes is the largest over ("": one probe)."""
        return ""

    # -- export hooks -------------------------------------------------------------------------
    def mujoco_terms(self, ctx: MujocoContext) -> MujocoTerms:
        """What the effect becomes in MuJoCo's model (:class:`MujocoTerms`; empty when
        MuJoCo cannot carry it, :attr:`MUJOCO_NOT_CARRIED` says why)."""
        return MujocoTerms()
