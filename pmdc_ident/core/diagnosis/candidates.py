"""Candidate models: the baseline plus one or more effects of the vocabulary.

Each candidate effect is first placed by a coarse scan (a few starting values
sized from the data, simulated with the baseline parameters held), then the
best start is refined by the identification core's output-error fit with the
baseline parameters free as well, on the fit segments only.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from pmdc_ident.core.data import Segment, heat_state
from pmdc_ident.core.diagnosis.scoring import NoiseModel, residuals
from pmdc_ident.core.effects import (
    EFFECT_NAMES,
    NO_COOLING_S,
    BrushDrop,
    Cogging,
    CoulombFriction,
    CurrentOffset,
    DeadZone,
    Delay,
    Effect,
    InductanceSaturation,
    LoadTorque,
    QuadraticDrag,
    ResistanceDrift,
    StribeckFriction,
)
from pmdc_ident.core.estimators.output_error import FitResult, fit_output_error
from pmdc_ident.core.model import Model, heat_time_constant, simulate, substeps_for

__all__ = [
    "BASE_FREE",
    "DataScales",
    "data_scales",
    "fit_model",
    "free_fields",
    "in_limit",
    "predict",
    "starting_effects",
]

BASE_FREE: tuple[str, ...] = ("R", "L", "Ke", "J", "B")
REFINE_BELOW_SAMPLES = 20_000


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
    periods_per_rev: tuple[int, ...]  # shaft-angle harmonics to try for cogging


def data_scales(segments: Sequence[Segment], kt: float, periods: Sequence[int] = ()) -> DataScales:
    cur = [s.current for s in segments if s.current is not None]
    i_all = np.concatenate(cur) if cur else np.zeros(1)
    v_all = np.concatenate([s.voltage for s in segments if s.voltage is not None] or [[1.0]])
    w_all = np.concatenate([s.speed_or_derivative() for s in segments])
    charge = sum(
        float(np.sum(s.current[:-1] ** 2 * np.diff(s.t)))
        for s in segments
        if s.current is not None
    )
    return DataScales(
        torque_nm=max(kt * float(np.sqrt(np.mean(i_all**2))), 1e-9),
        voltage_v=max(float(np.nanmax(np.abs(v_all))) if np.isfinite(v_all).any() else 1.0, 1e-6),
        speed_rad_s=max(float(np.max(np.abs(w_all))), 1e-6),
        current_a=max(float(np.max(np.abs(i_all))), 1e-6),
        dt_s=float(np.median([s.dt_s for s in segments])),
        charge_a2s=max(charge, 1e-9),
        span_s=max(float(max(s.t[-1] for s in segments) - min(s.t[0] for s in segments)), 1e-6),
        periods_per_rev=tuple(periods) or (1,),
    )


def _start(cls: type[Effect], *values: float) -> Effect:
    """``cls(*values)`` with each value moved into its physical range: a start sized
    from data in odd units must still be a valid effect, not an error."""
    specs = list(cls.SPECS.values())
    return cls(
        *(min(max(float(v), sp.lower), sp.upper) for v, sp in zip(values, specs, strict=True))
    )


def starting_effects(name: str, sc: DataScales) -> list[Effect]:
    """Starting values to scan for one effect, sized from the data (within its range)."""
    t, v, w = sc.torque_nm, sc.voltage_v, sc.speed_rad_s
    if name == "coulomb_friction":
        return [_start(CoulombFriction, t * f) for f in (0.03, 0.1, 0.3)]
    if name == "stribeck_friction":
        # the fall's speed over two decades of the top speed, in both common shapes
        # (exponential and Gaussian: measured curves lie between); the fit places the
        # torque, a start need only be of its order
        return [
            _start(StribeckFriction, t * 0.25, max(w * g, 1e-3), shape)
            for shape in (1.0, 2.0)
            for g in (0.005, 0.02, 0.08, 0.3)
        ]
    if name == "quadratic_drag":
        return [_start(QuadraticDrag, t * f / w**2) for f in (0.1, 0.3, 1.0)]
    if name == "load_torque":
        return [_start(LoadTorque, t * f) for f in (-0.2, -0.05, 0.05, 0.2)]
    if name == "brush_drop":
        # the hard sign (knee 0), then a contact film's knee at a share of the current
        hard = [_start(BrushDrop, v * f, 0.0) for f in (0.01, 0.02, 0.035, 0.05, 0.075, 0.1)]
        return hard + [
            _start(BrushDrop, v * f, sc.current_a * g)
            for f in (0.02, 0.05, 0.1)
            for g in (0.03, 0.1, 0.3)
        ]
    if name == "dead_zone":
        return [_start(DeadZone, v * f) for f in (0.01, 0.02, 0.035, 0.05, 0.075, 0.1)]
    if name == "cogging":
        return [
            _start(Cogging, t * 0.1, float(n), ph)
            for n in sc.periods_per_rev
            for ph in (-2.5, -1.0, 0.5, 2.0)
        ]
    if name == "resistance_drift":
        # first-order heating: q levels off near (mean i^2) x tau when tau < the span;
        # magnets that keep their flux (the diagnosis frees that only where heating helps)
        power = sc.charge_a2s / sc.span_s
        return [
            _start(ResistanceDrift, f / (power * min(tau, sc.span_s)), tau, 0.0)
            for f in (0.05, 0.2)
            for tau in (0.25 * sc.span_s, sc.span_s, NO_COOLING_S)
        ]
    if name == "delay":
        # every whole sample: at high sweep frequencies the cost wraps with the phase;
        # then a first-order lag behind a short transport delay (a drive's output filter)
        transport = [_start(Delay, min(k * sc.dt_s, 1.0), 0.0) for k in (*range(1, 25), 30, 40)]
        return transport + [
            _start(Delay, d * sc.dt_s, min(k * sc.dt_s, 1.0))
            for d in (0.0, 1.0)
            for k in (0.5, 1, 2, 4, 8, 16)
        ]
    if name == "current_offset":
        return [_start(CurrentOffset, sc.current_a * f) for f in (-0.05, -0.01, 0.01, 0.05)]
    if name == "inductance_saturation":
        return [_start(InductanceSaturation, max(sc.current_a * f, 1e-3)) for f in (0.5, 1.0, 2.0)]
    msg = f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}"
    raise ValueError(msg)


@dataclass(frozen=True)
class _Pred:
    current: np.ndarray
    speed: np.ndarray
    position: np.ndarray


def _x0(seg: Segment) -> list[float]:
    i0 = 0.0 if seg.current is None or seg.open_mask[0] else float(seg.current[0])
    th0 = float(seg.position[0]) if seg.position is not None else 0.0
    return [i0, float(seg.speed_or_derivative()[0]), th0]


def predict(model: Model, segments: Sequence[Segment], substeps: int = 4) -> list[_Pred]:
    """Free-run simulation of each segment from its measured initial state and history."""
    out = []
    tau = heat_time_constant(model)
    for s in segments:
        v = s.voltage if s.voltage is not None else np.full(s.n, math.nan)
        sim = simulate(
            model,
            v,
            s.dt_s,
            x0=_x0(s),
            substeps=substeps_for(model, substeps),
            pre_voltage=s.history_voltage,
            heat0_a2s=heat_state(s, tau),
        )
        out.append(_Pred(sim.current, sim.speed, sim.position))
    return out


def free_fields(e: Effect) -> tuple[str, ...]:
    """The fields a candidate fit estimates: an effect in its one-parameter limit holds
    the second field there (:meth:`~pmdc_ident.core.effects.Effect.free_names`). A
    resistance drift without cooling (the integral, ``time_constant_s`` at
    :data:`NO_COOLING_S`) costs one parameter, first-order heating two; a hard brush
    drop (``knee_current_a`` 0) one, a contact film's smooth drop two; a transport
    delay (``lag_s`` 0) one, one followed by a first-order lag two. A resistance
    drift whose magnets lose flux (``flux_loss_ratio`` above its limit 0) costs one
    more: the starts hold it at 0, the diagnosis frees it only where heating helps."""
    return e.free_names()


def in_limit(e: Effect) -> bool:
    """Whether ``e`` is its effect's one-parameter limit (see :func:`free_fields`)."""
    return len(free_fields(e)) == 1 < len(e.fitted_names())


def scan_start(
    base: Model,
    name: str,
    sc: DataScales,
    segments: Sequence[Segment],
    noise: NoiseModel,
    keep: Callable[[Effect], bool] | None = None,
) -> tuple[Model, float]:
    """The baseline plus the starting effect whose simulation best matches the data
    (among the starts ``keep`` accepts), and its gap on ``segments``.

    L is scanned too: when L/R is near the sample period the linear fit places L to
    mimic the effect (a delay most of all), and the fit holds L where it starts.
    """
    p = base.params
    factors = (1 / 3, 1 / 10, 1 / 30) if name == "delay" else (1 / 3, 3.0)
    bases = [base] + [Model(p.replace(L=p.L * f), base.effects) for f in factors]
    best, best_gap = None, math.inf
    for b in bases:
        for eff in starting_effects(name, sc):
            if keep is not None and not keep(eff):
                continue
            m = b.with_effects(eff)
            g = residuals(segments, predict(m, segments), noise).gap()
            if g < best_gap:
                best, best_gap = m, g
    assert best is not None
    return best, best_gap


def fit_model(
    segments: Sequence[Segment],
    model: Model,
    *,
    max_nfev: int,
    fixed: dict[str, float] | None = None,
) -> FitResult:
    """Output-error fit of the baseline parameters and every fitted effect parameter."""
    free = list(BASE_FREE)
    if fixed:
        free = [n for n in free if n not in fixed]
    for e in model.effects:
        free += [f"{e.NAME}.{f}" for f in free_fields(e)]
    # Large data: the engine's noise estimate is good, one pass is enough. Few samples
    # per segment (tables): the estimate degenerates, the residual re-weighting fixes it.
    small = sum(s.n for s in segments) < REFINE_BELOW_SAMPLES
    extra = {"refine_noise": small} if _ACCEPTS_REFINE else {}
    return fit_output_error(
        segments, model, free=free, fixed=fixed, closure="Kt=Ke", max_nfev=max_nfev, **extra
    )


_ACCEPTS_REFINE = "refine_noise" in inspect.signature(fit_output_error).parameters
