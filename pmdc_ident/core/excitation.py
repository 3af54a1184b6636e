"""Test signals and the default identification sequence (ROS-free).

A :class:`TestPlan` is an ordered tuple of :class:`PlannedSegment` objects: a
label (``staircase_03``, ``step_up``, ``sweep``, ``coast``...) and the voltage
command sampled on the driver's grid (NaN = armature open). The same plan drives
the identification node over ROS and :func:`synthesize_run` offline, so tests,
benchmarks and the node agree on what a session is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Run, Segment, TestKind, link_history, segment_kind
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.model import Model, simulate
from pmdc_ident.core.motors import Limits, MotorSpec, SensorSpec

__all__ = [
    "PlannedSegment",
    "SequenceConfig",
    "TestPlan",
    "apply_sensors",
    "default_plan",
    "log_chirp",
    "plan_for_motor",
    "synthesize_run",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class PlannedSegment:
    label: str
    voltage: FloatArray  # V per sample, NaN = armature open

    @property
    def kind(self) -> TestKind:
        return segment_kind(self.label)


@dataclass(frozen=True)
class TestPlan:
    __test__ = False  # not a pytest test class

    segments: tuple[PlannedSegment, ...]
    dt_s: float

    @property
    def n_samples(self) -> int:
        return sum(s.voltage.size for s in self.segments)

    @property
    def duration_s(self) -> float:
        return self.n_samples * self.dt_s


@dataclass(frozen=True)
class SequenceConfig:
    """What the default sequence runs. Voltages are fractions of the voltage limit.

    Durations are multiples of the mechanical time constant ``tau_m`` estimated
    from a nominal motor (or given in seconds when ``tau_m_s`` is set).
    """

    staircase: bool = True
    steps: bool = True
    sweep: bool = True
    coast: bool = True
    staircase_levels: int = 6
    staircase_max_fraction: float = 1.0
    staircase_hold_tau: float = 6.0
    step_fraction: float = 0.5
    step_hold_tau: float = 6.0
    step_directions: tuple[int, ...] = (1, -1)
    sweep_offset_fraction: float = 0.5
    sweep_amplitude_fraction: float = 0.3
    sweep_duration_tau: float = 40.0
    sweep_f_low_per_tau: float = 0.05
    sweep_f_high_hz: float = 0.0  # 0: a quarter of the sample rate
    coast_fraction: float = 1.0
    coast_spinup_tau: float = 6.0
    coast_open_s: float = 0.0  # 0: long enough to stop (estimated)

    def __post_init__(self) -> None:
        for name in (
            "staircase_max_fraction",
            "step_fraction",
            "sweep_offset_fraction",
            "coast_fraction",
        ):
            v = getattr(self, name)
            if not 0.0 < v <= 1.0:
                msg = f"{name} must lie in (0, 1] (a fraction of the voltage limit), got {v}"
                raise ParameterError(msg)
        if self.sweep_offset_fraction + self.sweep_amplitude_fraction > 1.0 + 1e-12:
            msg = "sweep offset + amplitude exceed the voltage limit"
            raise ParameterError(msg)
        if self.staircase_levels < 2:
            msg = f"staircase_levels must be >= 2, got {self.staircase_levels}"
            raise ParameterError(msg)


def log_chirp(
    n: int, dt_s: float, f0_hz: float, f1_hz: float, amplitude: float, offset: float = 0.0
) -> FloatArray:
    """Logarithmic (exponential) chirp from f0 to f1 over n samples."""
    if not (0 < f0_hz < f1_hz):
        msg = f"chirp needs 0 < f0 < f1, got f0={f0_hz}, f1={f1_hz}"
        raise ParameterError(msg)
    t = np.arange(n) * dt_s
    duration = n * dt_s
    k = math.log(f1_hz / f0_hz) / duration
    phase = 2.0 * math.pi * f0_hz * (np.exp(k * t) - 1.0) / k
    return offset + amplitude * np.sin(phase)


def default_plan(
    dt_s: float,
    limits: Limits,
    tau_m_s: float,
    config: SequenceConfig | None = None,
    *,
    coast_decel_time_s: float | None = None,
) -> TestPlan:
    """The default session: staircase, steps both ways, a log chirp, a coast-down."""
    cfg = config or SequenceConfig()
    if not (tau_m_s > 0 and math.isfinite(tau_m_s)):
        msg = f"mechanical time constant must be positive, got {tau_m_s}"
        raise ParameterError(msg)
    vmax = limits.voltage_max_v

    def samples(seconds: float) -> int:
        return max(2, int(round(seconds / dt_s)))

    segs: list[PlannedSegment] = []
    if cfg.staircase:
        levels = np.linspace(0, cfg.staircase_max_fraction * vmax, cfg.staircase_levels + 1)[1:]
        for idx, level in enumerate(levels, start=1):
            n = samples(cfg.staircase_hold_tau * tau_m_s)
            segs.append(PlannedSegment(f"staircase_{idx:02d}", np.full(n, level)))
    if cfg.steps:
        for direction in cfg.step_directions:
            name = "step_up" if direction > 0 else "step_down"
            n = samples(cfg.step_hold_tau * tau_m_s)
            # rest first (0 V), then the step, so the segment holds the whole transient
            v = np.full(n, direction * cfg.step_fraction * vmax)
            v[: max(2, n // 6)] = 0.0
            segs.append(PlannedSegment(name, v))
    if cfg.sweep:
        n = samples(cfg.sweep_duration_tau * tau_m_s)
        f0 = cfg.sweep_f_low_per_tau / tau_m_s
        f1 = cfg.sweep_f_high_hz or 0.25 / dt_s
        v = log_chirp(
            n,
            dt_s,
            f0,
            max(f1, 2 * f0),
            cfg.sweep_amplitude_fraction * vmax,
            cfg.sweep_offset_fraction * vmax,
        )
        segs.append(PlannedSegment("sweep", v))
    if cfg.coast:
        n_up = samples(cfg.coast_spinup_tau * tau_m_s)
        open_s = cfg.coast_open_s or coast_decel_time_s or 5.0 * tau_m_s
        v = np.concatenate(
            [np.full(n_up, cfg.coast_fraction * vmax), np.full(samples(open_s), np.nan)]
        )
        segs.append(PlannedSegment("coast", v))
    if not segs:
        msg = "the sequence configuration selects no test"
        raise ParameterError(msg)
    return TestPlan(tuple(segs), dt_s)


def apply_sensors(
    current: FloatArray,
    speed: FloatArray,
    position: FloatArray,
    sensors: SensorSpec,
    rng: np.random.Generator,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Measurement noise and encoder quantisation as the simulated driver applies them."""
    i = (
        current + rng.normal(0.0, sensors.current_noise_a, current.shape)
        if sensors.current_noise_a
        else current.copy()
    )
    w = (
        speed + rng.normal(0.0, sensors.speed_noise_rad_s, speed.shape)
        if sensors.speed_noise_rad_s
        else speed.copy()
    )
    if sensors.encoder_counts_per_rev > 0:
        step = 2.0 * math.pi / sensors.encoder_counts_per_rev
        th = np.floor(position / step) * step
    else:
        th = position.copy()
    return i, w, th


def synthesize_run(
    model: Model,
    plan: TestPlan,
    sensors: SensorSpec | None = None,
    *,
    seed: int | None = 0,
    substeps: int = 8,
    source: str = "simulation",
    signals: Sequence[str] = ("current", "position", "speed"),
) -> Run:
    """Simulate a whole plan on one continuous motor state and return it as a Run.

    Segments follow each other without a gap, as in a real session; ``signals``
    selects which measured columns the run carries.
    """
    v_all = np.concatenate([s.voltage for s in plan.segments])
    sim = simulate(model, v_all, plan.dt_s, substeps=substeps)
    rng = np.random.default_rng(seed)
    i, w, th = apply_sensors(sim.current, sim.speed, sim.position, sensors or SensorSpec(), rng)
    out: list[Segment] = []
    start = 0
    for ps in plan.segments:
        stop = start + ps.voltage.size
        sl = slice(start, stop)
        out.append(
            Segment(
                label=ps.label,
                t=sim.t[sl].copy(),
                voltage=ps.voltage.copy(),
                current=i[sl].copy() if "current" in signals else None,
                position=th[sl].copy() if "position" in signals else None,
                speed=w[sl].copy() if "speed" in signals else None,
            )
        )
        start = stop
    return Run(link_history(out), source)


def plan_for_motor(spec: MotorSpec, dt_s: float, config: SequenceConfig | None = None) -> TestPlan:
    """The default plan sized from a motor description (its tau_m, limits, coast time)."""
    p = spec.model.params
    tau = p.mechanical_time_constant_s
    # coast-down time from the no-load top speed under viscous + Coulomb friction
    cfg = config or SequenceConfig()
    _, w0 = p.steady_state(cfg.coast_fraction * spec.limits.voltage_max_v)
    tc = 0.0
    for name in ("coulomb_friction", "stribeck_friction"):
        e = spec.model.effect(name)
        tc += getattr(e, "torque_nm", 0.0) if e is not None else 0.0
    a = p.B / p.J
    if tc > 0 and a > 0:
        t_stop = math.log(1.0 + a * p.J * w0 / tc) / a
    elif tc > 0:
        t_stop = p.J * w0 / tc
    else:
        t_stop = 5.0 * p.J / max(p.B, 1e-12)
    return default_plan(
        dt_s, spec.limits, tau, cfg, coast_decel_time_s=min(1.2 * t_stop + 0.2, 60.0)
    )
