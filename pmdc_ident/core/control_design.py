"""Cascade PI gains (current loop, speed loop) designed from the identified motor.

The design is loop shaping on the identified linear model, with the sampling
delay of a digital controller included (the model of docs/design.md §2, units SI):

* **Current loop** (PI, output armature voltage V): the PI zero cancels the
  electrical pole, ``Ki/Kp = R/L``, and ``Kp = wc L``, so the open loop is
  ``wc/s e^{-s Td}`` with ``Td = 1.5 Ts`` (one sample of computation + half a
  sample of zero-order hold). Its phase margin is ``90 deg - wc Td``: a
  requested margin caps the crossover at ``(90 deg - PM)/Td``. The back-EMF
  ``Ke w`` is a slow disturbance the integral removes.
* **Speed loop** (PI, output current reference A): the plant is the closed
  current loop times ``Kt/(J s + B)``. At the requested crossover ``wc_s`` the
  PI time constant ``Ti`` supplies exactly the phase lag that leaves the
  requested margin, and ``Kp`` makes the loop gain one. If the plant already lags
  too much there, no PI can reach the margin: the design says so and names the
  largest crossover that can.

Both controllers run every sample ``Ts``, speed loop first, with forward-Euler
integrators and clamping anti-windup (:class:`CascadeController`).

What the design promises (overshoot and 2 % settling time of a speed step) is
the step response of the continuous loop with pure delays, simulated on a fine
grid (:func:`design_step_response`); :func:`verify_gains` then runs the real
discrete controller on :class:`~pmdc_ident.core.model.Plant` (the identified
model, or the motor with all its effects) and checks the measured overshoot and
settling against the promise (plus tolerances stated in :data:`TOLERANCES`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.model import Model, Plant
from pmdc_ident.core.motors import Limits, MotorSpec
from pmdc_ident.core.params import MotorParams

__all__ = [
    "TOLERANCES",
    "CascadeController",
    "ControlDesignError",
    "check_gains",
    "current_crossover_hz",
    "GainDesign",
    "LoopVerification",
    "StepMetrics",
    "design_gains",
    "design_step_response",
    "step_metrics",
    "verification_start_speed",
    "verify_gains",
]

# Slack between the promise (continuous design loop) and the discrete controller
# on the plant: overshoot in percentage points, settling as a factor.
TOLERANCES: dict[str, float] = {"overshoot_pp": 5.0, "settling_factor": 1.25}
_COMPUTE_DELAY_SAMPLES = 1.5  # one sample of computation + half a sample of ZOH
_SETTLING_BAND = 0.02


class ControlDesignError(PmdcError):
    """The requested bandwidth / phase margin cannot be met at this sample rate."""


@dataclass(frozen=True)
class StepMetrics:
    """Step response figures: overshoot in % of the step, 2 % settling time in s."""

    overshoot_pct: float
    settling_s: float
    step_rad_s: float


@dataclass(frozen=True)
class GainDesign:
    """Gains of the cascade and what the design promises (units in the names)."""

    sample_rate_hz: float
    phase_margin_deg: float
    current_kp_v_per_a: float
    current_ki_v_per_as: float
    current_crossover_hz: float
    current_phase_margin_deg: float
    speed_kp_a_s_per_rad: float
    speed_ki_a_per_rad: float
    speed_crossover_hz: float
    speed_phase_margin_deg: float
    voltage_max_v: float
    current_max_a: float
    promised: StepMetrics
    notes: tuple[str, ...] = ()

    @property
    def sample_period_s(self) -> float:
        return 1.0 / self.sample_rate_hz

    def as_dict(self) -> dict[str, object]:
        """The YAML/JSON form written by ``export-model --gains``."""
        return {
            "method": "loop shaping (PI zero on the electrical pole; PI speed for a phase margin)",
            "sample_rate_hz": self.sample_rate_hz,
            "current_loop": {
                "kp_v_per_a": self.current_kp_v_per_a,
                "ki_v_per_a_s": self.current_ki_v_per_as,
                "crossover_hz": self.current_crossover_hz,
                "phase_margin_deg": self.current_phase_margin_deg,
                "output_limit_v": self.voltage_max_v,
            },
            "speed_loop": {
                "kp_a_s_per_rad": self.speed_kp_a_s_per_rad,
                "ki_a_per_rad": self.speed_ki_a_per_rad,
                "crossover_hz": self.speed_crossover_hz,
                "phase_margin_deg": self.speed_phase_margin_deg,
                "output_limit_a": self.current_max_a,
            },
            "promised_speed_step": {
                "overshoot_pct": self.promised.overshoot_pct,
                "settling_2pct_s": self.promised.settling_s,
                "step_rad_s": self.promised.step_rad_s,
                "tolerances": dict(TOLERANCES),
            },
            "notes": list(self.notes),
        }


@dataclass(frozen=True)
class LoopVerification:
    """A discrete closed-loop speed step on one plant, against the promise."""

    plant: str
    measured: StepMetrics
    promised: StepMetrics
    peak_current_a: float
    peak_voltage_v: float
    time_s: np.ndarray = field(repr=False)
    speed_rad_s: np.ndarray = field(repr=False)

    @property
    def overshoot_ok(self) -> bool:
        limit = self.promised.overshoot_pct + TOLERANCES["overshoot_pp"]
        return self.measured.overshoot_pct <= limit

    @property
    def settling_ok(self) -> bool:
        limit = self.promised.settling_s * TOLERANCES["settling_factor"]
        return self.measured.settling_s <= limit

    @property
    def ok(self) -> bool:
        return self.overshoot_ok and self.settling_ok


# ---------------------------------------------------------------------------
def design_gains(
    params: MotorParams,
    limits: Limits,
    *,
    sample_rate_hz: float,
    speed_bandwidth_hz: float,
    phase_margin_deg: float = 60.0,
    current_bandwidth_hz: float | None = None,
) -> GainDesign:
    """PI current and speed gains for crossovers and a phase margin (see module doc).

    ``current_bandwidth_hz`` None takes the fastest current loop the margin and
    the sample rate allow (at most a tenth of the sample rate). The speed
    crossover must stay below a quarter of the current crossover.
    """
    _check_positive("sample_rate_hz", sample_rate_hz)
    _check_positive("speed_bandwidth_hz", speed_bandwidth_hz)
    if not 20.0 <= phase_margin_deg <= 85.0:
        msg = f"phase margin must lie in [20, 85] deg, got {phase_margin_deg:g}"
        raise ControlDesignError(msg)
    ts = 1.0 / sample_rate_hz
    td = _COMPUTE_DELAY_SAMPLES * ts
    pm = math.radians(phase_margin_deg)
    wci = (
        2 * math.pi * current_crossover_hz(sample_rate_hz, phase_margin_deg, current_bandwidth_hz)
    )
    kp_i = wci * params.L
    ki_i = wci * params.R
    wcs = 2 * math.pi * speed_bandwidth_hz
    if wcs > wci / 4:
        msg = (
            f"speed bandwidth {speed_bandwidth_hz:g} Hz is too close to the current loop's "
            f"{wci / (2 * math.pi):.3g} Hz: at most a quarter of it "
            f"({wci / (8 * math.pi):.3g} Hz)"
        )
        raise ControlDesignError(msg)
    g = _speed_plant(params, wci, td, wcs)
    lag_needed = -math.pi + pm - np.angle(g)  # phase the PI must add (negative = lag)
    notes = [
        f"loop delay {td * 1e3:.3g} ms ({_COMPUTE_DELAY_SAMPLES:g} samples: compute + ZOH)",
        "current loop: PI zero on the electrical pole R/L; back-EMF left to the integral",
    ]
    if lag_needed > 0.0:
        best = _max_speed_crossover(params, wci, td, pm)
        msg = (
            f"a PI speed loop cannot keep {phase_margin_deg:g} deg of margin at "
            f"{speed_bandwidth_hz:g} Hz (the plant lags too much there): at most "
            f"{best / (2 * math.pi):.3g} Hz"
        )
        raise ControlDesignError(msg)
    lag = max(lag_needed, -math.radians(89.0))
    if lag > lag_needed:
        notes.append("speed plant lags little: the margin is larger than asked")
    ti = 1.0 / (wcs * math.tan(-lag))
    kp_s = 1.0 / abs((1.0 + 1.0 / (1j * wcs * ti)) * g)
    ki_s = kp_s / ti
    pm_s = math.pi + float(np.angle((1.0 + 1.0 / (1j * wcs * ti)) * g))
    partial = GainDesign(
        sample_rate_hz=float(sample_rate_hz),
        phase_margin_deg=float(phase_margin_deg),
        current_kp_v_per_a=kp_i,
        current_ki_v_per_as=ki_i,
        current_crossover_hz=wci / (2 * math.pi),
        current_phase_margin_deg=math.degrees(math.pi / 2 - wci * td),
        speed_kp_a_s_per_rad=kp_s,
        speed_ki_a_per_rad=ki_s,
        speed_crossover_hz=speed_bandwidth_hz,
        speed_phase_margin_deg=math.degrees(pm_s),
        voltage_max_v=limits.voltage_max_v,
        current_max_a=limits.current_max_a,
        promised=StepMetrics(0.0, 0.0, 0.0),
        notes=tuple(notes),
    )
    step = _verification_step(partial, params, limits)
    t, w = design_step_response(partial, params, step)
    promised = step_metrics(t, w, 0.0, step)
    return GainDesign(**{**partial.__dict__, "promised": promised})


def current_crossover_hz(
    sample_rate_hz: float, phase_margin_deg: float, requested_hz: float | None = None
) -> float:
    """The current loop's crossover: ``requested_hz`` if the margin allows it, else an
    error; None takes the largest allowed (at most a tenth of the sample rate)."""
    _check_positive("sample_rate_hz", sample_rate_hz)
    td = _COMPUTE_DELAY_SAMPLES / sample_rate_hz
    wc_max = min(
        (math.pi / 2 - math.radians(phase_margin_deg)) / td, 2 * math.pi * sample_rate_hz / 10
    )
    if requested_hz is None:
        return wc_max / (2 * math.pi)
    _check_positive("current_bandwidth_hz", requested_hz)
    if 2 * math.pi * requested_hz > wc_max * (1 + 1e-9):
        msg = (
            f"a {requested_hz:g} Hz current loop at {sample_rate_hz:g} Hz sampling cannot keep "
            f"a {phase_margin_deg:g} deg margin (delay {td * 1e3:.3g} ms): at most "
            f"{wc_max / (2 * math.pi):.3g} Hz"
        )
        raise ControlDesignError(msg)
    return float(requested_hz)


def _speed_plant(params: MotorParams, wci: float, td: float, w: float) -> complex:
    """Closed current loop times Kt/(J s + B) at frequency w (rad/s)."""
    li = wci / (1j * w) * np.exp(-1j * w * td)
    return complex(li / (1 + li) * params.Kt / (1j * w * params.J + params.B))


def _max_speed_crossover(params: MotorParams, wci: float, td: float, pm: float) -> float:
    lo, hi = 1e-3, wci / 4
    for _ in range(60):
        mid = math.sqrt(lo * hi)
        if -math.pi + pm - np.angle(_speed_plant(params, wci, td, mid)) > 0:
            hi = mid
        else:
            lo = mid
    return lo


def _check_positive(name: str, value: float) -> None:
    if not (math.isfinite(value) and value > 0):
        msg = f"{name} must be a positive number, got {value}"
        raise ControlDesignError(msg)


def _verification_step(design: GainDesign, params: MotorParams, limits: Limits) -> float:
    """A speed step that keeps the linear loop away from the current and voltage limits.

    The current reference jumps by ``Kp_s step`` and the voltage by about
    ``(Kp_i + R) Kp_s step``, on top of the back-EMF: each stays within 30 % of its
    limit.
    """
    kp_s = design.speed_kp_a_s_per_rad
    by_current = 0.3 * limits.current_max_a / kp_s
    by_voltage = (
        0.3 * limits.voltage_max_v / ((design.current_kp_v_per_a + params.R) * kp_s + params.Ke)
    )
    return float(min(0.2 * limits.speed_max_rad_s, by_current, by_voltage))


def verification_start_speed(params: MotorParams, limits: Limits) -> float:
    """Where a step on a motor with friction starts: turning, with voltage headroom."""
    return float(min(0.3 * limits.speed_max_rad_s, 0.3 * limits.voltage_max_v / params.Ke))


# ---------------------------------------------------------------------------
def design_step_response(
    design: GainDesign, params: MotorParams, step_rad_s: float, duration_s: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The design loop's speed step from rest: continuous PIs, pure delay, linear motor.

    Integrated on a grid 20x finer than the sample period (the electrical pole
    exactly, via the ZOH step of the motor), so it is the loop the gains were
    shaped for, not the sampled implementation.
    """
    ts = design.sample_period_s
    h = ts / 20.0
    n_delay = round(_COMPUTE_DELAY_SAMPLES * 20)
    duration = duration_s or _duration(design)
    n = int(duration / h)
    plant = Plant(Model(params), h, substeps=1)
    buf = np.zeros(n_delay + 1)
    xi_s = xi_i = 0.0
    w_out = np.empty(n)
    for k in range(n):
        w, i = plant.speed_rad_s, plant.current_a
        w_out[k] = w
        e_s = step_rad_s - w
        i_ref = design.speed_kp_a_s_per_rad * e_s + xi_s
        xi_s += design.speed_ki_a_per_rad * e_s * h
        e_i = i_ref - i
        v = design.current_kp_v_per_a * e_i + xi_i
        xi_i += design.current_ki_v_per_as * e_i * h
        buf = np.roll(buf, 1)
        buf[0] = v
        plant.step(float(buf[n_delay]))
    return np.arange(n) * h, w_out


def _duration(design: GainDesign) -> float:
    return max(12.0 / (2 * math.pi * design.speed_crossover_hz), 40 * design.sample_period_s)


def step_metrics(t: np.ndarray, w: np.ndarray, w0: float, step: float) -> StepMetrics:
    """Overshoot (% of the step) and 2 % settling time of a step from ``w0`` to ``w0 + step``."""
    y = (np.asarray(w) - w0) / step
    overshoot = max(0.0, float(y.max()) - 1.0) * 100.0
    outside = np.flatnonzero(np.abs(y - 1.0) > _SETTLING_BAND)
    if outside.size == 0:
        settling = 0.0
    elif outside[-1] == y.size - 1:
        settling = math.inf
    else:
        settling = float(t[outside[-1] + 1] - t[0])
    return StepMetrics(overshoot, settling, float(step))


# ---------------------------------------------------------------------------
class CascadeController:
    """The discrete cascade as a drive would run it, one call per sample.

    ``update(speed_ref, speed, current)`` returns the voltage to apply over the
    next sample (the caller delays it by one sample). Forward-Euler integrators;
    an integrator stops while its output is clamped (anti-windup).
    """

    def __init__(self, design: GainDesign) -> None:
        self.d = design
        self.xi_speed = 0.0
        self.xi_current = 0.0

    def update(self, speed_ref: float, speed: float, current: float) -> float:
        d, ts = self.d, self.d.sample_period_s
        e_s = speed_ref - speed
        i_ref, sat_i = _clamp(d.speed_kp_a_s_per_rad * e_s + self.xi_speed, d.current_max_a)
        e_i = i_ref - current
        v, sat_v = _clamp(d.current_kp_v_per_a * e_i + self.xi_current, d.voltage_max_v)
        if sat_v * e_i <= 0.0:  # integrate unless it pushes further into the clamp
            self.xi_current = _clamp(
                self.xi_current + d.current_ki_v_per_as * e_i * ts, d.voltage_max_v
            )[0]
        # The speed integrator also waits while the voltage is clamped (the current
        # then cannot follow its reference).
        if sat_i * e_s <= 0.0 and sat_v * e_s <= 0.0:
            self.xi_speed = _clamp(
                self.xi_speed + d.speed_ki_a_per_rad * e_s * ts, d.current_max_a
            )[0]
        return v


def _clamp(value: float, limit: float) -> tuple[float, float]:
    """``value`` clamped to +-limit, and the side clamped (+1, -1 or 0)."""
    if value > limit:
        return limit, 1.0
    if value < -limit:
        return -limit, -1.0
    return value, 0.0


def verify_gains(
    design: GainDesign, model: Model, *, label: str, start_rad_s: float = 0.0
) -> LoopVerification:
    """Run the discrete cascade on ``model`` (8 sub-steps per sample): a speed step.

    The loop first ramps to ``start_rad_s`` and holds it until it is steady, then
    steps by the promised step size. A model with friction should start away from rest
    (``start_rad_s`` > 0) so the step does not cross zero speed.
    """
    ts = design.sample_period_s
    plant = Plant(model, ts)
    ctrl = CascadeController(design)
    n_settle = int(math.ceil(max(2.0 * _duration(design), 0.2) / ts))
    n_step = int(math.ceil(_duration(design) / ts))
    v_next = 0.0
    for k in range(n_settle):
        ref = start_rad_s * min(1.0, 2.0 * k / n_settle)
        v = ctrl.update(ref, plant.speed_rad_s, plant.current_a)
        plant.step(v_next)
        v_next = v
    w0 = plant.speed_rad_s
    target = start_rad_s + design.promised.step_rad_s
    w = np.empty(n_step)
    peak_i = peak_v = 0.0
    for k in range(n_step):
        w[k] = plant.speed_rad_s
        peak_i = max(peak_i, abs(plant.current_a))
        v = ctrl.update(target, plant.speed_rad_s, plant.current_a)
        peak_v = max(peak_v, abs(v))
        plant.step(v_next)
        v_next = v
    t = np.arange(n_step) * ts
    measured = step_metrics(t, w, w0, target - w0)
    return LoopVerification(label, measured, design.promised, peak_i, peak_v, t, w)


def check_gains(
    design: GainDesign, spec: MotorSpec, others: Sequence[MotorSpec] = ()
) -> list[LoopVerification]:
    """The speed step on the identified linear model, on ``spec``'s model with its
    effects (when it has any) and on each of ``others`` (e.g. the simulated true motor)."""
    p = spec.model.params
    start = verification_start_speed(p, spec.limits)
    checks = [verify_gains(design, Model(p), label="identified linear model", start_rad_s=start)]
    if spec.model.effects:
        names = "+".join(spec.model.effect_names)
        checks.append(
            verify_gains(
                design, spec.model, label=f"identified model ({names})", start_rad_s=start
            )
        )
    for other in others:
        checks.append(verify_gains(design, other.model, label=other.name, start_rad_s=start))
    return checks
