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
from pmdc_ident.core.effects import EFFECT_NAMES, EFFECT_TYPES, DataScales, Effect
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


def starting_effects(name: str, sc: DataScales) -> list[Effect]:
    """Starting values to scan for one effect, sized from the data (within its range):
    the effect's own :meth:`~pmdc_ident.core.effects.base.Effect.starts`."""
    cls = EFFECT_TYPES.get(name)
    if cls is None:
        msg = f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}"
        raise ValueError(msg)
    return list(cls.starts(sc))


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

    L is scanned too (the effect's ``L_SCAN`` factors): when L/R is near the sample
    period the linear fit places L to mimic the effect (a delay most of all), and the
    fit holds L where it starts.
    """
    p = base.params
    factors = EFFECT_TYPES[name].L_SCAN
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
