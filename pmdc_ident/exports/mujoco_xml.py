"""The identified motor as MuJoCo MJCF: a hinge joint driven by the motor's actuator.

Written as plain XML (no ``mujoco`` import is needed to write it). Two actuator
flavours, both commanded in volts (``ctrl`` = armature voltage):

* ``dcmotor`` (MuJoCo >= 4): MuJoCo's DC motor actuator with the winding
  resistance, the inductance (the armature current is its activation state) and
  the motor constant. MuJoCo's motor has one constant ``K`` for torque and
  back-EMF; an identified motor has two (Kt, Ke). The export keeps the speed
  response exact by giving MuJoCo ``K = Ke`` and scaling R and L by ``Ke/Kt``:
  then ``L' di'/dt = V - R' i' - Ke w`` and ``torque = Ke i' = Kt i`` with
  ``i' = i Kt/Ke``, so MuJoCo's actuator current reads ``Kt/Ke`` times the real
  one (stated in the file).
* ``general`` (any MuJoCo): a general actuator with the same torque-speed law,
  ``torque = (Kt/R) filt(V) - (Kt Ke/R) w`` where ``filt`` is a first-order lag
  ``L/R`` on the voltage (``dyntype=filterexact``). It neglects the inductance's lag
  of the back-EMF term, an error of order ``(L/R)/(J R/(Kt Ke))``.

Rotor inertia, viscous friction and Coulomb friction go on the joint, reflected
through the gear ``N`` (``armature = J N^2``, ``damping = B N^2``, ``frictionloss
= Tc N``); the actuator's ``gear`` is ``N``, so ``<dcmotor>``'s own terms act in the
motor shaft's angle, speed and torque. Each effect of the model says what it becomes
(:meth:`~pmdc_ident.core.effects.base.Effect.mujoco_terms`, its mapping in words in
``MUJOCO_MAPPING``, docs/mujoco.md) or why MuJoCo cannot carry it
(``MUJOCO_NOT_CARRIED``): a quadratic drag the joint's second damping coefficient, a
Stribeck friction ``<dcmotor lugre>`` (with the Coulomb friction as its Coulomb
level), cogging ``<dcmotor cogging>``, winding heating ``<dcmotor thermal>``, a
transport delay the actuator's ``delay``, a drive's first-order lag a drive joint in front
of the motor (:func:`_drive`), a constant load a passive ``<dcmotor>``.
The motor file's current limit becomes ``<dcmotor saturation>`` (the torque a
current-limited drive delivers at most). What is not carried is listed in
:attr:`MujocoExport.not_carried` and in the file. The ``general`` flavour (MuJoCo < 4)
carries the joint's terms only.

:func:`~pmdc_ident.exports.diagnosis.motor_with_diagnosis` turns a diagnosis into the
model exported here (``export-model --diagnosis``).
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from pmdc_ident.core.effects import MujocoContext
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.motors import MotorSpec
from pmdc_ident.core.params import MotorParams

__all__ = [
    "MUJOCO_FLAVOURS",
    "MujocoExport",
    "installed_mujoco_flavour",
    "mapping_table",
    "mujoco_xml",
]

MUJOCO_FLAVOURS: tuple[str, ...] = ("dcmotor", "general")

# LuGre bristles as stiff as the model's step resolves: their resonance with the rotor
# sqrt(sigma0 / J) x step = LUGRE_OMEGA_STEP (explicit); softer bristles ring against the
# rotor where the project's model holds it stuck (the 24 V scooter's held-out step down:
# the current 0.076 A RMS off the model's, its noise 0.059 A, at 1e-4 rad of deflection)
LUGRE_OMEGA_STEP = 0.3
# LuGre's Coulomb level at least this share of the Stribeck torque: MuJoCo divides by
# g(v), which a Gaussian fall alone takes to 0 (underflow) at high speed; its bristle
# state is integrated exactly, so a floor far under any measurable torque is stable at
# any step (checked at 2e-5 to 1e-3 s). A floor of 2 % of Ts was a Coulomb friction
# the model does not have (the 48 V scooter's fitted fall: -31 % shrink in MuJoCo)
LUGRE_FLOOR = 1e-6
# a drive's first-order lag: the drive joint's damping D = DRIVE_STIFFNESS / R (N*m*s/rad
# per V of the drive's speed); the winding's current reacts on it, an error of i / D =
# R i / DRIVE_STIFFNESS in the lagged voltage
DRIVE_STIFFNESS = 1e6

_ALWAYS_NOTED = (
    "open armature (coast-down): MuJoCo's motor has no open circuit; ctrl = 0 V shorts "
    "the winding and brakes",
    "the motor's speed limit (MuJoCo has no velocity limit on a joint)",
)


@dataclass(frozen=True)
class MujocoExport:
    """The MJCF text and what it leaves out."""

    xml: str
    flavour: str
    joint: str
    actuator: str
    timestep_s: float
    not_carried: tuple[str, ...]
    notes: tuple[str, ...]
    carried: tuple[str, ...] = ()  # "<effect>: how it is carried", one per effect

    def write(self, path: str | Path) -> Path:
        from pmdc_ident.core.safe_write import write_text

        return write_text(path, self.xml)


def installed_mujoco_flavour() -> str:
    """``dcmotor`` unless an installed ``mujoco`` package predates the DC motor actuator.

    The version is read from the package's metadata, not by importing it: writing an
    export (the identification node does, beside a bag) never loads MuJoCo."""
    from importlib import metadata

    try:
        version = metadata.version("mujoco")
    except metadata.PackageNotFoundError:
        return "dcmotor"
    head = version.split(".")[0]
    return "dcmotor" if not head.isdigit() or int(head) >= 4 else "general"


def mujoco_xml(
    spec: MotorSpec,
    *,
    reduction: float = 1.0,
    joint: str = "motor_joint",
    flavour: str | None = None,
    timestep_s: float = 2.5e-4,
    thermal_reference_k: float = 0.0,
) -> MujocoExport:
    """MJCF of the motor ``spec`` behind a gear of ratio ``reduction`` (motor turns per
    joint turn); ``flavour`` None picks :func:`installed_mujoco_flavour`.
    ``thermal_reference_k``: with winding heating, the rise above ambient (K) at which
    MuJoCo's inductance is the model's (MuJoCo keeps L/R as R heats; see
    :func:`_dcmotor_terms`); 0, ambient, by default."""
    if not (math.isfinite(thermal_reference_k) and thermal_reference_k >= 0.0):
        msg = f"thermal reference must be a finite rise >= 0 K, got {thermal_reference_k!r}"
        raise ParameterError(msg)
    flavour = flavour or installed_mujoco_flavour()
    _check_arguments(flavour, reduction, timestep_s)
    p, n = spec.model.params, float(reduction)
    terms = _Terms.collect(spec, n, flavour)
    plan = terms.friction_plan(p.J, timestep_s)

    root = ET.Element("mujoco", model=spec.name or "pmdc_motor")
    ET.SubElement(root, "option", timestep=_f(timestep_s), gravity="0 0 0")
    world = ET.SubElement(root, "worldbody")
    body = ET.SubElement(world, "body", name=f"{joint}_output")
    damping = _f(p.B * n * n)
    if terms.damping2 > 0 and flavour == "dcmotor":
        damping = f"{damping} {_f(terms.damping2)}"
    joint_attrs = {
        "name": joint,
        "type": "hinge",
        "axis": "0 0 1",
        "armature": _f(p.J * n * n),
        "damping": damping,
        "frictionloss": _f(plan.frictionloss_nm * n),
    }
    if plan.frictionloss_nm > 0:
        # MuJoCo's default friction constraint (20 ms) smears a Coulomb torque over tens
        # of ms: as stiff as the step allows (two steps, MuJoCo's floor)
        joint_attrs["solreffriction"] = f"{_f(2 * timestep_s)} 1"
    ET.SubElement(body, "joint", **joint_attrs)
    # The rotor's inertia is the joint armature; the body itself is nearly massless.
    ET.SubElement(body, "inertial", pos="0 0 0", mass="1e-6", diaginertia="1e-12 1e-12 1e-12")
    vmax = spec.limits.voltage_max_v
    notes = [f"ctrl is the armature voltage in V (limited to +-{vmax:g} V)"]
    common = {
        "name": f"{joint}_motor",
        "joint": joint,
        "gear": _f(n),
        "ctrllimited": "true",
        "ctrlrange": f"{_f(-vmax)} {_f(vmax)}",
    }
    act = ET.SubElement(root, "actuator")
    lagged = flavour == "dcmotor" and terms.lag_s > 0
    drive = None
    if lagged:
        drive, common = _drive(root, world, act, joint, n, p, terms.lag_s, common)
    notes.append(_actuator(act, flavour, common, p))
    if lagged:
        act.append(drive)  # the motor stays the first actuator, the drive the one with ctrl
        notes.append(
            f"a drive's first-order lag ({terms.lag_s:.4g} s): actuator '{joint}_drive' takes "
            f"ctrl (V) and turns joint '{joint}_drive' at the lagged voltage (rad/s = V); the "
            f"motor '{joint}_motor' has no input and acts on tendon '{joint}_drive', the motor "
            "shaft's angle minus the drive joint's over K, so its back-EMF K (w - V_lag / K) "
            "puts the lagged voltage across the winding; its friction and cogging act on "
            "passive elements of the joint"
        )
    if flavour == "dcmotor":
        notes += _dcmotor_terms(
            act[0], spec, terms, plan, timestep_s, thermal_reference_k, drive=drive
        )
        if lagged and (plan.lugre is not None or any(terms.cogging)):
            for attr in ("lugre", "cogging"):  # one passive element each
                if attr in act[0].attrib:
                    _passive(act, f"{joint}_{attr}", joint, n, **{attr: act[0].attrib.pop(attr)})
        for k, lugre in enumerate(plan.more, start=2):
            _passive(act, f"{joint}_stribeck{k}", joint, n, lugre=" ".join(_f(x) for x in lugre))
        if plan.more:
            notes.append(
                f"actuators '{joint}_stribeck2'... are Gaussian Stribeck falls beside the motor's "
                "own: passive dcmotors whose LuGre friction sums with it to the exponential fall"
            )
        if terms.constant_nm:
            cogging = f"{_f(terms.constant_nm)} 0 {_f(-math.pi / 2)}"
            _passive(act, f"{joint}_load", joint, n, cogging=cogging)
            notes.append(
                f"actuator '{joint}_load' is the load torque ({terms.constant_nm:.4g} N*m at the "
                "motor, against +w): a passive dcmotor whose zero-pole cogging is constant; "
                "remove it where your scene models the load"
            )
    text = ET.tostring(root, encoding="unicode")
    header = _comment(spec, n, flavour, notes, terms.carried, terms.not_carried)
    xml = _pretty(header + text)
    return MujocoExport(
        xml=xml,
        flavour=flavour,
        joint=joint,
        actuator=f"{joint}_motor",
        timestep_s=timestep_s,
        not_carried=terms.not_carried,
        notes=tuple(notes),
        carried=terms.carried,
    )


def _passive(act: ET.Element, name: str, joint: str, n: float, **terms: str) -> None:
    """A passive ``<dcmotor>`` on the joint (no input, no motor constant): its friction
    or cogging ``terms`` act on the joint and nothing else."""
    ET.SubElement(
        act,
        "dcmotor",
        name=name,
        joint=joint,
        gear=_f(n),
        input="none",
        resistance="1",
        motorconst="0 0",
        **terms,
    )


def mapping_table() -> str:
    """Every effect of the registry and what the MuJoCo export makes of it (markdown;
    docs/mujoco.md prints it, a test keeps the two equal)."""
    from pmdc_ident.core.effects import EFFECT_TYPES

    lines = ["| effect | in MuJoCo | how |", "|---|---|---|"]
    for name, cls in EFFECT_TYPES.items():
        if cls.MUJOCO_MAPPING:
            lines.append(f"| `{name}` | carried | {cls.MUJOCO_MAPPING} |")
        else:
            lines.append(f"| `{name}` | not carried | {cls.MUJOCO_NOT_CARRIED} |")
    return "\n".join(lines)


def _check_arguments(flavour: str, reduction: float, timestep_s: float) -> None:
    if flavour not in MUJOCO_FLAVOURS:
        msg = f"MuJoCo actuator flavour must be one of {', '.join(MUJOCO_FLAVOURS)}, got {flavour}"
        raise ParameterError(msg)
    if not (math.isfinite(reduction) and reduction > 0):
        msg = f"gear reduction must be a positive number, got {reduction}"
        raise ParameterError(msg)
    if not (math.isfinite(timestep_s) and 0 < timestep_s <= 0.01):
        msg = f"MuJoCo timestep must lie in (0, 0.01] s, got {timestep_s}"
        raise ParameterError(msg)


@dataclass(frozen=True)
class _Friction:
    """How the dry friction is written: the joint's ``frictionloss`` (Coulomb alone) or
    ``<dcmotor lugre>`` (with a Stribeck term), at the motor shaft."""

    frictionloss_nm: float = 0.0
    lugre: tuple[float, float, float, float, float] | None = None
    floor_note: str = ""
    more: tuple[tuple[float, float, float, float, float], ...] = ()  # passive elements' lugre


@dataclass
class _Terms:
    """Every effect's MuJoCo terms, summed, with what is and is not carried."""

    coulomb_nm: float = 0.0
    damping2: float = 0.0
    stribeck: tuple[float, float] = (0.0, 0.0)
    stribeck_more: tuple[tuple[float, float], ...] = ()
    cogging: tuple[float, float, float] = (0.0, 0.0, 0.0)
    thermal: tuple[float, float, float] = (0.0, 0.0, 0.0)
    delay_s: float = 0.0
    lag_s: float = 0.0
    constant_nm: float = 0.0
    carried: tuple[str, ...] = ()
    not_carried: tuple[str, ...] = ()

    @classmethod
    def collect(cls, spec: MotorSpec, n: float, flavour: str) -> _Terms:
        p = spec.model.params
        ctx = MujocoContext(
            reduction=n, resistance_ohm=p.R * p.Ke / p.Kt, current_scale=p.Kt / p.Ke
        )
        out = cls()
        carried: list[str] = []
        missing: list[str] = []
        for e in spec.model.effects:
            if e.MUJOCO_NOT_CARRIED:
                missing.append(f"{e.NAME}: {e.MUJOCO_NOT_CARRIED}")
                continue
            t = e.mujoco_terms(ctx)
            joint_only = t.coulomb_nm and not t.stribeck[0]
            if flavour == "general" and not joint_only:
                missing.append(f"{e.NAME}: needs MuJoCo >= 4 (<dcmotor> and polynomial damping)")
                continue
            out.coulomb_nm += t.coulomb_nm
            out.damping2 += t.joint_damping2
            if t.stribeck[0]:
                out.stribeck = t.stribeck
                out.stribeck_more = t.stribeck_more
            if any(t.cogging):
                out.cogging = t.cogging
            if any(t.thermal):
                out.thermal = t.thermal
            out.delay_s += t.delay_s
            out.lag_s += t.lag_s
            out.constant_nm += t.constant_torque_nm
            carried.append(f"{e.NAME}: {e.MUJOCO_MAPPING}")
            if t.partial:
                missing.append(f"{e.NAME}: {t.partial}")
        missing += list(_ALWAYS_NOTED)
        if not math.isclose(p.Kt, p.Ke, rel_tol=1e-9):
            missing.append(
                f"Kt != Ke (Kt/Ke = {p.Kt / p.Ke:.6g}): MuJoCo's dcmotor has one motor constant "
                "(motorconst 'Kt Ke' is taken as their geometric mean); the file uses K = Ke "
                "and scales R and L by Ke/Kt, so speed and torque are exact and the current "
                "state reads i Kt/Ke"
            )
        out.carried, out.not_carried = tuple(carried), tuple(missing)
        return out

    def friction_plan(self, inertia_motor: float, timestep_s: float) -> _Friction:
        ts, vs = self.stribeck
        if ts <= 0:
            return _Friction(frictionloss_nm=self.coulomb_nm)
        fc = max(self.coulomb_nm, LUGRE_FLOOR * ts)
        note = ""
        if fc > self.coulomb_nm:
            note = (
                f"LuGre's Coulomb level is {fc:.4g} N*m, {LUGRE_FLOOR:g} of the Stribeck torque "
                "(MuJoCo's bristle equation needs g(v) > 0 at every speed)"
            )
        # (static level, Coulomb level, Stribeck speed) of each LuGre element: the motor's
        # own, then the passive ones of further Gaussian falls (floors of their own)
        levels = [(fc + ts, fc, vs)] + [
            ((1.0 + LUGRE_FLOOR) * t, LUGRE_FLOOR * t, v) for t, v in self.stribeck_more
        ]
        # bristles as stiff as the step resolves (all elements' stiffness together, each
        # in proportion to its static level: omega h = LUGRE_OMEGA_STEP, explicit);
        # no bristle damping: MuJoCo's damping force sigma1 dz/dt takes dz/dt at the
        # step's start while it integrates z exactly, so with it the friction depends on
        # the step (a 6 V step and a sine through zero on a 2 ohm motor: 4.7 rad/s RMS off
        # the candidate at 50 steps per sample, 1.2 at 200; without it 0.48 at any step)
        stiff = inertia_motor * (LUGRE_OMEGA_STEP / timestep_s) ** 2
        total = sum(fs for fs, _, _ in levels)
        lugre = [(stiff * fs / total, 0.0, c, fs, v) for fs, c, v in levels]
        return _Friction(lugre=lugre[0], floor_note=note, more=tuple(lugre[1:]))


def _dcmotor_terms(
    el: ET.Element,
    spec: MotorSpec,
    terms: _Terms,
    plan: _Friction,
    timestep_s: float,
    reference_k: float = 0.0,
    *,
    drive: ET.Element | None = None,
) -> list[str]:
    """The ``<dcmotor>`` attributes of the effects and the limits; the notes they need.

    Heating: MuJoCo's winding is R(T) = R_ref (1 + alpha' (T - reftemp)) with its
    electrical time constant fixed at L/R_ref, so its inductance rises with R (L(T) =
    L R(T)/R_ref); the model's L is the winding's at every temperature. The two agree
    at reftemp only: with a reference rise D, resistance R (1 + alpha D), alpha' =
    alpha / (1 + alpha D) and reftemp 25 + D give the same R(T) = R (1 + alpha T) and
    MuJoCo's L = the model's at T = D (ambient 25 C, T the rise above it). MuJoCo heats
    by R(T) i^2 where the model heats by R i^2: capacitance C (1 + alpha D) and thermal
    resistance R_th / (1 + alpha D) make its heating rate the model's at T = D too, with
    the same time constant."""
    notes = []
    p = spec.model.params
    if any(terms.cogging):
        el.set("cogging", " ".join(_f(x) for x in terms.cogging))
    if any(terms.thermal):
        rth, c, alpha = terms.thermal
        grow = 1.0 + alpha * reference_k
        el.set("resistance", _f(float(el.get("resistance", "0")) * grow))
        el.set(
            "thermal",
            f"{_f(rth / grow)} {_f(c * grow)} 0 {_f(alpha / grow)} {_f(25.0 + reference_k)} 25",
        )
        notes.append(
            "thermal: the winding's rise T above 25 C ambient in the actuator's temperature "
            f"activation; R(T) = R (1 + alpha T), written at the reference {reference_k:.4g} K "
            "above ambient (resistance R (1 + alpha D), tempcoef alpha / (1 + alpha D), "
            "capacitance C (1 + alpha D): heated at R(T) i^2, the model's rate at D); "
            "MuJoCo keeps L/R as R heats, so its inductance is the winding's at the reference "
            "rise only, (1 + alpha T) / (1 + alpha D) times it elsewhere"
        )
    if plan.lugre is not None:
        el.set("lugre", " ".join(_f(x) for x in plan.lugre))
        notes.append(
            f"lugre: bristle stiffness chosen for a {timestep_s:g} s step (at a larger step lower "
            "it: its resonance sqrt(sigma0 / J) x step <= 0.3), no bristle damping (MuJoCo "
            "takes its force from dz/dt at the step's start: the friction would depend on the "
            "step)"
        )
        if plan.floor_note:
            notes.append(plan.floor_note)
    if terms.delay_s > 0:
        nsample = int(math.ceil(terms.delay_s / timestep_s)) + 2
        (drive if drive is not None else el).set("delay", _f(terms.delay_s))
        (drive if drive is not None else el).set("nsample", str(nsample))
        notes.append(
            f"delay: the command is read {terms.delay_s:.4g} s late from MuJoCo's ctrl history "
            f"(nsample {nsample} at this step: keep delay <= nsample x timestep)"
        )
    torque_max = p.Kt * spec.limits.current_max_a
    el.set("saturation", f"{_f(torque_max)} 0 0")
    notes.append(
        f"saturation: the motor file's current limit {spec.limits.current_max_a:g} A as a "
        f"torque limit Kt I_max = {torque_max:.4g} N*m at the motor (what a current-limited "
        "drive delivers at most; MuJoCo's current itself is not limited)"
    )
    return notes


def _drive(
    root: ET.Element,
    world: ET.Element,
    act: ET.Element,
    joint: str,
    n: float,
    p: MotorParams,
    lag_s: float,
    common: dict[str, str],
) -> tuple[ET.Element, dict[str, str]]:
    """A drive's first-order lag in front of the winding: a drive joint whose speed is the
    lagged voltage, ``lag_s D dw/dt = D (V - w)`` (armature ``lag_s D``, damping ``D``,
    a ``<general>`` actuator of gain ``D`` that takes ``ctrl``), and a fixed tendon of the
    motor shaft's angle minus the drive joint's over K, on which the motor (no input of
    its own) acts: its back-EMF ``K (w_motor - w_drive / K)`` is the motor's minus the
    lagged voltage. The winding's torque reacts on the drive joint (``-i``, against ``D V``):
    an error of ``i / D`` volts, ``R i / DRIVE_STIFFNESS``. Returns the drive actuator (to
    be placed after the motor, which stays the first actuator) and the motor's attributes."""
    damping = DRIVE_STIFFNESS / (p.R * p.Ke / p.Kt)
    name = f"{joint}_drive"
    body = ET.SubElement(world, "body", name=name)
    ET.SubElement(body, "joint", name=name, type="hinge", axis="0 0 1",
                  armature=_f(lag_s * damping), damping=_f(damping))  # fmt: skip
    ET.SubElement(body, "inertial", pos="0 0 0", mass="1e-6", diaginertia="1e-12 1e-12 1e-12")
    tendon = ET.Element("tendon")
    fixed = ET.SubElement(tendon, "fixed", name=name)
    ET.SubElement(fixed, "joint", joint=joint, coef=_f(n))
    ET.SubElement(fixed, "joint", joint=name, coef=_f(-1.0 / p.Ke))
    root.insert(list(root).index(act), tendon)
    limits = {k: common[k] for k in ("ctrllimited", "ctrlrange")}
    drive = ET.Element("general", name=name, joint=name, gainprm=_f(damping), **limits)
    motor = {"name": common["name"], "tendon": name, "gear": "1", "input": "none"}
    return drive, motor


def _actuator(act: ET.Element, flavour: str, common: dict[str, str], p: MotorParams) -> str:
    """The motor's actuator element in ``act``; returns the note it needs."""
    if flavour == "dcmotor":
        scale = p.Ke / p.Kt
        ET.SubElement(
            act,
            "dcmotor",
            **common,
            resistance=_f(p.R * scale),
            motorconst=f"{_f(p.Ke)} {_f(p.Ke)}",
            inductance=f"{_f(p.L * scale)} 0",
        )
        return (
            f"MuJoCo's K = Ke; R and L scaled by Ke/Kt = {scale:.6g}, so the actuator's "
            f"current state reads i * Kt/Ke (speed and torque are exact)"
        )
    ET.SubElement(
        act,
        "general",
        **common,
        dyntype="filterexact",
        dynprm=_f(p.L / p.R),
        gaintype="fixed",
        gainprm=_f(p.Kt / p.R),
        biastype="affine",
        biasprm=f"0 0 {_f(-p.Kt * p.Ke / p.R)}",
    )
    return "the inductance lags the voltage only, not the back-EMF (see module doc)"


def _f(x: float) -> str:
    return f"{x:.10g}"


def _comment(
    spec: MotorSpec,
    n: float,
    flavour: str,
    notes: list[str],
    carried: tuple[str, ...],
    not_carried: tuple[str, ...],
) -> str:
    p = spec.model.params
    lines = [
        f"MJCF written by pmdc-ident export-model from motor '{spec.name}' ({flavour} actuator).",
        f"R={p.R:.6g} ohm L={p.L:.6g} H Ke={p.Ke:.6g} V*s/rad Kt={p.Kt:.6g} N*m/A "
        f"J={p.J:.6g} kg*m^2 B={p.B:.6g} N*m*s/rad; gear reduction {n:g}.",
        *notes,
    ]
    if carried:
        lines += ["Effects carried:", *(f"  - {item}" for item in carried)]
    lines += ["Not carried by this MuJoCo model:", *(f"  - {item}" for item in not_carried)]
    body = "\n".join(f"  {line}".replace("--", "- -") for line in lines)
    return f"<!--\n{body}\n-->\n"


def _pretty(text: str) -> str:
    comment, _, rest = text.partition("-->\n")
    tree = ET.ElementTree(ET.fromstring(rest))
    ET.indent(tree, space="  ")
    return comment + "-->\n" + ET.tostring(tree.getroot(), encoding="unicode") + "\n"
