"""A brushed DC motor simulated by MuJoCo's own ``<dcmotor>`` actuator (MuJoCo >= 4).

Equations and an integrator nobody in this project wrote. MuJoCo's DC motor
(``src/engine/engine_forward.c``, the ``dcmotor`` technical note) holds the armature
current as an activation state, ``di/dt = (V/R - K w/R - i) / te`` with ``te = L/R``,
integrated exactly over each step; the torque is ``K i``, clamped by ``saturation``;
``cogging`` adds ``A sin(poles theta + phase)`` in the actuator's own angle (the motor
shaft's, ``gear`` x the joint's); ``thermal`` heats the winding,
``dT/dt = (R(T) i^2 - T/R_th) / C`` with ``R(T) = R (1 + alpha T)`` (and ``te`` kept,
so L grows with R); ``lugre`` is a LuGre bristle state with a Gaussian Stribeck
curve, ``dz/dt = v - sigma0 |v| z / g(v)``, ``g(v) = Fc + (Fs - Fc) exp(-(v/vs)^2)``,
force ``-(sigma0 z + sigma1 dz/dt)``, integrated exactly; the actuator's ``delay``
reads the command from MuJoCo's own history buffer. The hinge joint carries the
rotor's inertia (``armature``), a polynomial damping ``-(a w + b w|w| + c w^3)`` and
a Coulomb ``frictionloss`` (a soft constraint of MuJoCo's solver). A load can sit
behind the shaft on a second body: a mass on a slide joint tied to the shaft by a
fixed tendon with a spring and a damper (a cable on a drum, under gravity), or a load
inertia on a second hinge with a spring and a damper, or with free play (joint
limits: backlash).

What a driver adds outside the motor is applied outside MuJoCo, at every MuJoCo step:
the drive's dead zone and its first-order output lag on the commanded voltage, a
brush contact drop ``Vb tanh(i / i0)`` from MuJoCo's current (MuJoCo's motor has no
such term), the open armature of a coast-down (MuJoCo's motor cannot open its
circuit: its constant is set to 0 and its current to 0 while the command is NaN, so
no torque and no back-EMF current, while cogging, LuGre friction and the joint act
on), and the sensors' analog filters (exact for a signal linear over each step).
Noise, quantisation and the encoder's counts are :mod:`.sensors`' (the same models
as the project's own generator).

A benchmark/test dependency only: ``mujoco`` is imported inside the functions that
simulate, and nothing in identify, diagnose or the nodes imports this module
(``test/test_mujoco_optional.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "Chain",
    "DcMotor",
    "Filters",
    "MjPlant",
    "Passive",
    "mjcf",
    "plant_mjcf",
    "simulate",
    "simulate_plant",
    "substeps_for",
]

FloatArray = NDArray[np.float64]

_XML = """<mujoco model="pmdc">
  <option timestep="{timestep}" gravity="0 0 0" integrator="{integrator}">
    <flag contact="disable"/>
  </option>
  <worldbody>
    <body name="rotor">
      <inertial pos="0 0 0" mass="1e-6" diaginertia="1e-12 1e-12 1e-12"/>
      <joint name="shaft" type="hinge" axis="0 0 1" armature="{J}" damping="{B}"
             frictionloss="{frictionloss}" solreffriction="{solref} 1"/>
    </body>
  </worldbody>
  <actuator>
    <dcmotor name="motor" joint="shaft" resistance="{R}" motorconst="{K} {K}"
             inductance="{L} 0"/>
  </actuator>
</mujoco>"""


@dataclass(frozen=True)
class DcMotor:
    """MuJoCo's DC motor: one constant ``K`` (= Kt = Ke in SI units), winding ``R`` and
    ``L``, rotor inertia ``J``, viscous ``B``, Coulomb friction ``frictionloss`` (N*m)."""

    R: float
    L: float
    K: float
    J: float
    B: float
    frictionloss: float = 0.0


def mjcf(motor: DcMotor, timestep_s: float, integrator: str = "Euler") -> str:
    """The MJCF of ``motor`` (a friction constraint stiff at 0.5 ms, so a Coulomb torque
    is not smeared over MuJoCo's default 20 ms)."""
    return _XML.format(
        timestep=f"{timestep_s:.10g}",
        integrator=integrator,
        solref="0.0005",
        J=f"{motor.J:.10g}",
        B=f"{motor.B:.10g}",
        frictionloss=f"{motor.frictionloss:.10g}",
        R=f"{motor.R:.10g}",
        K=f"{motor.K:.10g}",
        L=f"{motor.L:.10g}",
    )


def simulate(
    motor: DcMotor,
    voltage: FloatArray,
    dt_s: float,
    *,
    substeps: int = 200,
    x0: tuple[float, float, float] = (0.0, 0.0, 0.0),
    integrator: str = "Euler",
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Current, speed and angle at each sample of ``voltage`` (V, held over each of its
    samples; MuJoCo cannot open the circuit, so NaN is refused), from ``x0`` = (i, w,
    theta). ``substeps`` MuJoCo steps per sample period.

    The integrator matters for the current: with ``Euler`` MuJoCo's dcmotor follows the
    exact zero-order-hold solution to 1e-5 A at 100 steps per sample (a small motor,
    L/R 0.5 ms, 1 kHz), while ``RK4`` lags it by about half a step (L read 4.5 % high at
    20 steps per sample, still 1.7 % of the current's first step at 100); the speed's
    error is first order in the step either way (0.14 rad/s of 300 at 100 steps)."""
    import mujoco

    v = np.asarray(voltage, dtype=float)
    if not np.isfinite(v).all():
        msg = "MuJoCo's dcmotor cannot open its armature: the voltage must be finite"
        raise ValueError(msg)
    model = mujoco.MjModel.from_xml_string(mjcf(motor, dt_s / substeps, integrator))
    data = mujoco.MjData(model)
    data.act[0], data.qvel[0], data.qpos[0] = x0
    n = v.size
    cur, spd, pos = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        cur[k], spd[k], pos[k] = data.act[0], data.qvel[0], data.qpos[0]
        data.ctrl[0] = v[k]
        mujoco.mj_step(model, data, substeps)
    return cur, spd, pos


# ---------------------------------------------------------------------------------------
# The benchmark plant: every effect <dcmotor> or the joint can express
# ---------------------------------------------------------------------------------------
GRAVITY = 9.81
AMBIENT_C = 25.0  # the thermal model's ambient = reference temperature: R(0) = R
MIN_SUBSTEPS = 50  # MuJoCo steps per sample at least: its half-step lag is 1 % of a sample
MAX_SUBSTEPS = 4000


@dataclass(frozen=True)
class Passive:
    """A passive ``<dcmotor>`` on the shaft (``input="none"``, motor constant 0: no
    electrical branch): its own cogging ``A sin(poles x gear x theta + phase)`` in its
    own angle, the joint's times ``gear`` (a gear mesh's teeth, a second harmonic)."""

    amplitude_nm: float  # in the passive actuator's space (times gear at the joint)
    poles: float
    phase_rad: float
    gear: float = 1.0


@dataclass(frozen=True)
class MjPlant:
    """One MuJoCo model: the motor at the measured (joint) shaft and what MuJoCo adds.

    ``K`` is the constant at the joint (SI, Kt = Ke); behind a gear of ``gear`` motor
    turns per joint turn the ``<dcmotor>`` gets ``K / gear`` and ``gear``, so its
    cogging, LuGre friction and saturation act in the motor shaft's angle and torque.
    Zeros (the defaults) leave a feature out."""

    R: float
    L: float
    K: float
    J: float  # at the joint, rotor and coupled load
    B: float
    gear: float = 1.0
    # the joint
    frictionloss: float = 0.0  # N*m at the joint
    damping2: float = 0.0  # b of -(a w + b w|w| + c w^3)
    damping3: float = 0.0  # c
    # the dcmotor (motor shaft: torque, angle, speed)
    cogging: tuple[float, float, float] = (0.0, 0.0, 0.0)  # amplitude N*m, poles, phase
    thermal: tuple[float, float, float] = (0.0, 0.0, 0.0)  # R_th K/W, C J/K, tempcoef 1/K
    lugre: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    saturation: tuple[float, float, float] = (0.0, 0.0, 0.0)  # torque, current, di/dt max
    delay_s: float = 0.0  # the actuator's command delay (MuJoCo's ctrl history)
    passive: tuple[Passive, ...] = ()
    # loads on the joint
    applied_nm: float = 0.0  # a constant torque opposing +w (qfrc_applied)
    lift_mass_kg: float = 0.0  # a mass on a slide joint, under gravity ...
    drum_radius_m: float = 0.0  # ... tied to the shaft by a cable on a drum (x = r theta):
    cable_stiffness: float = 0.0  # a fixed tendon x - r theta with a spring (N/m) ...
    cable_damping: float = 0.0  # ... and a damper (N*s/m)
    load_inertia: float = 0.0  # a second body on a hinge behind the rotor ...
    coupling_stiffness: float = 0.0  # ... through a spring (N*m/rad) ...
    coupling_damping: float = 0.0  # ... and a damper
    backlash_rad: float = 0.0  # ... or free play of +-gap (joint limits)
    limit_timeconst_s: float = 0.0  # the play's end stops (solreflimit)

    @property
    def motor_inertia(self) -> float:
        """The joint's inertia seen at the motor shaft (kg*m^2)."""
        return self.J / self.gear**2


@dataclass(frozen=True)
class Chain:
    """What the drive does to the command before MuJoCo's motor, and a brush contact
    drop MuJoCo's motor lacks, applied outside MuJoCo at each of its steps."""

    dead_zone: int = 0  # 1 hard (zero inside +-V), 2 soft (v - V tanh(v/V))
    dead_zone_v: float = 0.0
    lag_s: float = 0.0  # first-order lag of the drive's output
    brush_v: float = 0.0  # Vb tanh(i / i0) subtracted from the terminal voltage
    brush_knee_a: float = 0.0


@dataclass(frozen=True)
class Filters:
    """The sensors' analog filters: cascaded first-order stages (0 Hz: none)."""

    current_fc_hz: float = 0.0
    current_order: int = 1
    speed_fc_hz: float = 0.0


def _f(x: float) -> str:
    return f"{float(x):.10g}"


def _vec(xs: tuple[float, ...]) -> str:
    return " ".join(_f(x) for x in xs)


def plant_mjcf(p: MjPlant, timestep_s: float, friction_timeconst_s: float) -> str:
    """The MJCF of plant ``p`` at MuJoCo step ``timestep_s`` (constraints' time
    constants are at least two steps: MuJoCo's own floor)."""
    tf = max(friction_timeconst_s, 2.0 * timestep_s)
    gravity = GRAVITY if p.lift_mass_kg > 0 else 0.0
    damping = _vec((p.B, p.damping2, p.damping3))
    bodies = [
        '    <body name="rotor">',
        '      <inertial pos="0 0 0" mass="1e-6" diaginertia="1e-12 1e-12 1e-12"/>',
        f'      <joint name="shaft" type="hinge" axis="0 0 1" armature="{_f(p.J)}" '
        f'damping="{damping}" frictionloss="{_f(p.frictionloss)}" '
        f'solreffriction="{_f(tf)} 1"/>',
    ]
    if p.load_inertia > 0:
        limit = ""
        if p.backlash_rad > 0:
            tl = max(p.limit_timeconst_s, 2.0 * timestep_s)
            limit = (
                f' limited="true" range="{_f(-p.backlash_rad)} {_f(p.backlash_rad)}" '
                f'solreflimit="{_f(tl)} 1"'
            )
        bodies += [
            '      <body name="load">',
            f'        <inertial pos="0 0 0" mass="1e-6" diaginertia="{_f(p.load_inertia)} '
            f'{_f(p.load_inertia)} {_f(p.load_inertia)}"/>',
            f'        <joint name="coupling" type="hinge" axis="0 0 1" '
            f'stiffness="{_f(p.coupling_stiffness)}" damping="{_f(p.coupling_damping)}"'
            f"{limit}/>",
            "      </body>",
        ]
    bodies.append("    </body>")
    tendon = ""
    if p.lift_mass_kg > 0:
        # a cable on a drum: a fixed tendon x - r theta with a spring and a damper (a
        # soft joint equality is no cable: its force falls with the drum's speed, MuJoCo's
        # constraint impedance letting the mass slip)
        bodies += [
            '    <body name="lift" pos="1 0 0">',
            f'      <inertial pos="0 0 0" mass="{_f(p.lift_mass_kg)}" '
            'diaginertia="1e-9 1e-9 1e-9"/>',
            '      <joint name="lift" type="slide" axis="0 0 1"/>',
            "    </body>",
        ]
        tendon = (
            "  <tendon>\n"
            f'    <fixed name="cable" stiffness="{_f(p.cable_stiffness)}" '
            f'damping="{_f(p.cable_damping)}" springlength="0">\n'
            '      <joint joint="lift" coef="1"/>\n'
            f'      <joint joint="shaft" coef="{_f(-p.drum_radius_m)}"/>\n'
            "    </fixed>\n"
            "  </tendon>\n"
        )
    motor = [
        f'    <dcmotor name="motor" joint="shaft" gear="{_f(p.gear)}" '
        f'resistance="{_f(p.R)}" motorconst="{_f(p.K / p.gear)} {_f(p.K / p.gear)}" '
        f'inductance="{_f(p.L)} 0"'
    ]
    if any(p.cogging):
        motor.append(f'cogging="{_vec(p.cogging)}"')
    if any(p.thermal):
        rth, c, alpha = p.thermal
        motor.append(f'thermal="{_f(rth)} {_f(c)} 0 {_f(alpha)} {AMBIENT_C:g} {AMBIENT_C:g}"')
    if any(p.lugre):
        motor.append(f'lugre="{_vec(p.lugre)}"')
    if any(p.saturation):
        motor.append(f'saturation="{_vec(p.saturation)}"')
    if p.delay_s > 0:
        nsample = int(math.ceil(p.delay_s / timestep_s)) + 2
        motor.append(f'delay="{_f(p.delay_s)}" nsample="{nsample}"')
    actuators = [" ".join(motor) + "/>"]
    for k, q in enumerate(p.passive):
        actuators.append(
            f'    <dcmotor name="passive_{k}" joint="shaft" gear="{_f(q.gear)}" input="none" '
            f'resistance="1" motorconst="0 0" '
            f'cogging="{_f(q.amplitude_nm)} {_f(q.poles)} {_f(q.phase_rad)}"/>'
        )
    return (
        '<mujoco model="pmdc_benchmark">\n'
        f'  <option timestep="{_f(timestep_s)}" gravity="0 0 {_f(-gravity)}" '
        'integrator="Euler">\n'
        '    <flag contact="disable"/>\n'
        "  </option>\n"
        "  <worldbody>\n" + "\n".join(bodies) + "\n  </worldbody>\n" + tendon + "  <actuator>\n"
        "" + "\n".join(actuators) + "\n  </actuator>\n</mujoco>\n"
    )


def substeps_for(p: MjPlant, chain: Chain, dt_s: float) -> int:
    """MuJoCo steps per sample: at least :data:`MIN_SUBSTEPS`, and fine enough for the
    stiffest thing present (explicit steps of a spring need h omega < ~0.3)."""
    limits = [dt_s / MIN_SUBSTEPS]
    sig0 = p.lugre[0]
    if sig0 > 0:  # the bristles' spring on the motor shaft's inertia
        limits.append(0.3 / math.sqrt(sig0 / p.motor_inertia))
    if p.load_inertia > 0 and p.coupling_stiffness > 0:
        k = p.coupling_stiffness
        limits.append(0.3 / math.sqrt(k * (1.0 / p.J + 1.0 / p.load_inertia)))
    if p.load_inertia > 0 and p.backlash_rad > 0 and p.limit_timeconst_s > 0:
        limits.append(p.limit_timeconst_s / 4.0)
    if p.lift_mass_kg > 0 and p.cable_stiffness > 0:
        m_eff = 1.0 / (1.0 / p.lift_mass_kg + p.drum_radius_m**2 / p.J)
        limits.append(0.3 / math.sqrt(p.cable_stiffness / m_eff))
    if chain.brush_v > 0 and chain.brush_knee_a > 0:
        # the drop's slope Vb/i0 is a resistance applied one step late: keep it below
        # the winding's L/step
        limits.append(0.5 * p.L / (chain.brush_v / chain.brush_knee_a))
    n = int(math.ceil(dt_s / min(limits) - 1e-9))
    return max(n, MIN_SUBSTEPS)


def _dead_zone(v: FloatArray, chain: Chain) -> FloatArray:
    d = chain.dead_zone_v
    if chain.dead_zone == 1:
        return np.where(np.abs(v) > d, v, 0.0)
    if chain.dead_zone == 2:
        return v - d * np.tanh(v / d)
    return v


def _foh_filter(u: FloatArray, h: float, fc_hz: float, order: int) -> FloatArray:
    """``order`` cascaded first-order stages at ``fc_hz`` of a signal linear between its
    samples (exact for such a signal), from rest at the signal's first value."""
    from scipy.signal import lfilter

    if fc_hz <= 0:
        return u
    a = 2.0 * math.pi * fc_hz
    e = math.exp(-a * h)
    c = (1.0 - e) / (a * h)
    y = u
    for _ in range(order):
        zi = np.array([c * y[0]])  # before the first sample: y = u = y[0] (at rest)
        y = lfilter([1.0 - c, c - e], [1.0, -e], y, zi=zi)[0]
    return y


def simulate_plant(
    p: MjPlant,
    command_v: FloatArray,
    dt_s: float,
    *,
    chain: Chain | None = None,
    filters: Filters | None = None,
    friction_timeconst_s: float | None = None,
    max_substeps: int = MAX_SUBSTEPS,
):  # type: ignore[no-untyped-def]
    """Simulate a whole record from rest in MuJoCo (NaN command = armature open); the
    benchmark's :class:`~pmdc_ident.benchmark.plant.SimOutput` (true and analog-filtered
    signals at each sample's start; the winding's temperature rise in K)."""
    from pmdc_ident.exports.mujoco_replay import mujoco_warnings_caught

    with mujoco_warnings_caught() as caught:
        out = _simulate(p, command_v, dt_s, chain, filters, friction_timeconst_s, max_substeps)
    if caught:
        msg = f"MuJoCo's simulation went unstable: {caught[0].strip()}"
        raise ValueError(msg)
    return out


def _simulate(p, command_v, dt_s, chain, filters, friction_timeconst_s, max_substeps):  # type: ignore[no-untyped-def]
    import mujoco

    from pmdc_ident.benchmark.plant import SimOutput

    chain = chain or Chain()
    filters = filters or Filters()
    if chain.brush_v > 0 and p.delay_s > 0:
        msg = "a brush drop acts in the motor: it cannot pass through the command's delay"
        raise ValueError(msg)
    nsub = substeps_for(p, chain, dt_s)
    if nsub > max_substeps:
        msg = f"MuJoCo plant too stiff for the sample period: {nsub} steps per sample"
        raise ValueError(msg)
    h = dt_s / nsub
    tf = dt_s / 5.0 if friction_timeconst_s is None else friction_timeconst_s
    model = mujoco.MjModel.from_xml_string(plant_mjcf(p, h, tf))
    data = mujoco.MjData(model)
    motor = 0
    adr0, nact = int(model.actuator_actadr[motor]), int(model.actuator_actnum[motor])
    cur = adr0 + nact - 1  # the current is the dcmotor's last activation slot
    temp = adr0 if any(p.thermal) else -1  # slot order: temperature, bristle, current
    k_motor = float(model.actuator_gainprm[motor, 1])
    if p.applied_nm:
        data.qfrc_applied[0] = -p.applied_nm
    if p.lift_mass_kg > 0 and p.cable_stiffness > 0:
        data.qpos[1] = -p.lift_mass_kg * GRAVITY / p.cable_stiffness  # the cable stretched

    cmd = np.asarray(command_v, dtype=float)
    n = cmd.size
    is_open = np.isnan(cmd)
    v = _dead_zone(np.where(is_open, 0.0, cmd), chain)
    v_fine = np.repeat(v, nsub)
    if chain.lag_s > 0:
        # the drive's first-order lag of the held command, exact: its state at each
        # step's start (y), and over the step its mean, which MuJoCo holds
        from scipy.signal import lfilter

        e = math.exp(-h / chain.lag_s)
        y = lfilter([0.0, 1.0 - e], [1.0, -e], v_fine)
        v_fine = v_fine + (y - v_fine) * (chain.lag_s / h) * (1.0 - e)
    nf = n * nsub + 1
    i_fine = np.zeros(nf)
    w_fine = np.zeros(nf)
    pos = np.zeros(n)
    temp_k = np.zeros(n)
    brush = chain.brush_v > 0
    vb, i0 = chain.brush_v, max(chain.brush_knee_a, 1e-12)
    gainprm = model.actuator_gainprm
    act, qvel, qpos, ctrl = data.act, data.qvel, data.qpos, data.ctrl
    step = mujoco.mj_step
    was_open = False
    j = 0
    for k in range(n):
        pos[k] = qpos[0]
        temp_k[k] = act[temp] if temp >= 0 else 0.0
        if is_open[k] != was_open:
            was_open = bool(is_open[k])
            gainprm[motor, 1] = 0.0 if was_open else k_motor
        if was_open:
            act[cur] = 0.0
        for _ in range(nsub):
            u = v_fine[j]
            if brush and not was_open:
                u -= vb * math.tanh(act[cur] / i0)
            ctrl[0] = u
            step(model, data)
            if was_open:
                act[cur] = 0.0
            j += 1
            i_fine[j] = act[cur]
            w_fine[j] = qvel[0]
    gainprm[motor, 1] = k_motor
    unstable = int(data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number)
    if unstable or not (np.isfinite(i_fine).all() and np.isfinite(w_fine).all()):
        msg = f"MuJoCo's simulation went unstable ({unstable} resets at {nsub} steps per sample)"
        raise ValueError(msg)
    idx = np.arange(n) * nsub
    i_f = _foh_filter(i_fine, h, filters.current_fc_hz, filters.current_order)
    w_f = _foh_filter(w_fine, h, filters.speed_fc_hz, 1)
    rec = np.column_stack([i_fine[idx], w_fine[idx], pos, i_f[idx], w_f[idx], temp_k, temp_k * 0])
    out = SimOutput(rec, dt_s)
    out.substeps = nsub  # type: ignore[attr-defined]
    return out
