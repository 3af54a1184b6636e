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
= Tc N``; a quadratic drag ``Cq`` becomes the joint's second damping coefficient
``Cq N^3``, MuJoCo >= 4). The actuator's ``gear`` is ``N``. Each effect says what it
adds to the joint (:meth:`~pmdc_ident.core.effects.base.Effect.mujoco_joint`) or why
MuJoCo's model cannot carry it (``MUJOCO_NOT_CARRIED``); those are listed in
:attr:`MujocoExport.not_carried` and in the file.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.motors import MotorSpec
from pmdc_ident.core.params import MotorParams

__all__ = ["MUJOCO_FLAVOURS", "MujocoExport", "installed_mujoco_flavour", "mujoco_xml"]

MUJOCO_FLAVOURS: tuple[str, ...] = ("dcmotor", "general")

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

    def write(self, path: str | Path) -> Path:
        from pmdc_ident.core.safe_write import write_text

        return write_text(path, self.xml)


def installed_mujoco_flavour() -> str:
    """``dcmotor`` unless an installed ``mujoco`` package predates the DC motor actuator."""
    try:
        import mujoco  # noqa: PLC0415 - optional, only to choose the flavour
    except ImportError:
        return "dcmotor"
    major = int(str(getattr(mujoco, "__version__", "4")).split(".")[0] or 0)
    return "dcmotor" if major >= 4 else "general"


def mujoco_xml(
    spec: MotorSpec,
    *,
    reduction: float = 1.0,
    joint: str = "motor_joint",
    flavour: str | None = None,
    timestep_s: float = 2.5e-4,
) -> MujocoExport:
    """MJCF of the motor ``spec`` behind a gear of ratio ``reduction`` (motor turns per
    joint turn); ``flavour`` None picks :func:`installed_mujoco_flavour`."""
    flavour = flavour or installed_mujoco_flavour()
    _check_arguments(flavour, reduction, timestep_s)
    p, n = spec.model.params, float(reduction)
    joint_terms = _joint_terms(spec, n)
    frictionloss = joint_terms.get("frictionloss", 0.0)  # Tc N
    damping2 = joint_terms.get("damping2", 0.0)  # Cq N^3
    not_carried = _not_carried(spec, flavour, n)

    root = ET.Element("mujoco", model=spec.name or "pmdc_motor")
    ET.SubElement(root, "option", timestep=_f(timestep_s), gravity="0 0 0")
    world = ET.SubElement(root, "worldbody")
    body = ET.SubElement(world, "body", name=f"{joint}_output")
    damping = (
        _f(p.B * n * n)
        if not (damping2 > 0 and flavour == "dcmotor")
        else (f"{_f(p.B * n * n)} {_f(damping2)}")
    )
    ET.SubElement(
        body,
        "joint",
        name=joint,
        type="hinge",
        axis="0 0 1",
        armature=_f(p.J * n * n),
        damping=damping,
        frictionloss=_f(frictionloss),
    )
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
    notes.append(_actuator(ET.SubElement(root, "actuator"), flavour, common, p))
    text = ET.tostring(root, encoding="unicode")
    header = _comment(spec, n, flavour, notes, not_carried)
    xml = _pretty(header + text)
    return MujocoExport(
        xml=xml,
        flavour=flavour,
        joint=joint,
        actuator=f"{joint}_motor",
        timestep_s=timestep_s,
        not_carried=not_carried,
        notes=tuple(notes),
    )


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


def _joint_terms(spec: MotorSpec, n: float) -> dict[str, float]:
    """What the model's effects add to the joint (``frictionloss``, ``damping2``)."""
    terms: dict[str, float] = {}
    for e in spec.model.effects:
        for key, value in e.mujoco_joint(n).items():
            terms[key] = terms.get(key, 0.0) + value
    return terms


def _not_carried(spec: MotorSpec, flavour: str, n: float) -> tuple[str, ...]:
    """What of the motor's model the MJCF cannot carry, one line each."""
    out = tuple(
        f"{e.NAME}: {e.MUJOCO_NOT_CARRIED}" for e in spec.model.effects if e.MUJOCO_NOT_CARRIED
    )
    out += _ALWAYS_NOTED
    if flavour == "general":
        out += tuple(
            f"{e.NAME}: polynomial joint damping needs MuJoCo >= 4"
            for e in spec.model.effects
            if e.mujoco_joint(n).get("damping2", 0.0) > 0
        )
    return out


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
    spec: MotorSpec, n: float, flavour: str, notes: list[str], not_carried: tuple[str, ...]
) -> str:
    p = spec.model.params
    lines = [
        f"MJCF written by pmdc-ident export-model from motor '{spec.name}' ({flavour} actuator).",
        f"R={p.R:.6g} ohm L={p.L:.6g} H Ke={p.Ke:.6g} V*s/rad Kt={p.Kt:.6g} N*m/A "
        f"J={p.J:.6g} kg*m^2 B={p.B:.6g} N*m*s/rad; gear reduction {n:g}.",
        *notes,
        "Not carried by this MuJoCo model:",
        *(f"  - {item}" for item in not_carried),
    ]
    body = "\n".join(f"  {line}".replace("--", "- -") for line in lines)
    return f"<!--\n{body}\n-->\n"


def _pretty(text: str) -> str:
    comment, _, rest = text.partition("-->\n")
    tree = ET.ElementTree(ET.fromstring(rest))
    ET.indent(tree, space="  ")
    return comment + "-->\n" + ET.tostring(tree.getroot(), encoding="unicode") + "\n"
