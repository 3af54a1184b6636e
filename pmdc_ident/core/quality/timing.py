"""Timing checks: sample period and jitter, gaps, and whether ``t`` is in seconds at all.

A motor's electrical time constant is at most tens of milliseconds and its
mechanical one at most tens of seconds; when the record, read in seconds, puts
them far beyond that (or samples a time series once a second for hours), the
time column is in other units. The unit that puts the sample period and the
time constants back in range is the fix offered.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.quality.findings import Finding, Severity
from pmdc_ident.core.quality.regress import MIN_DYNAMIC, arx_pole, dynamic, memoised

__all__ = ["check_time_unit", "check_timing", "cut_at_gaps", "time_constants_s"]

# Largest plausible electrical (L/R) and mechanical time constants of a motor, s.
TAU_E_MAX_S = 0.5
TAU_M_MAX_S = 60.0
# A time series sampled slower than this (s) over many samples is suspect.
DT_MAX_S = 0.5
_JITTER_TOL = 0.05  # relative deviation of one interval from the median that counts as jitter
_GAP = 1.5  # an interval this many median periods long is a gap
_UNITS = (("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9))


def _fmt_period(dt_s: float) -> str:
    if dt_s >= 0.9999:
        return f"{dt_s:.4g} s"
    if dt_s >= 0.9999e-3:
        return f"{dt_s * 1e3:.4g} ms"
    return f"{dt_s * 1e6:.4g} us"


def cut_at_gaps(segments: Sequence[Segment]) -> tuple[Segment, ...]:
    """Each time series cut at its gaps (an interval over ``_GAP`` median periods: samples
    missing) into the pieces between them, ``label.1``, ``label.2``...; tables and
    series without a gap as they are.

    What the checks that compare a sample with the next one read: across a gap nobody
    knows what the motor did (a board that reset mid-run restarts its encoder count, a
    dropped burst of samples hides half a turn), so a position difference, a current
    step or a regression row spanning it says nothing about units or physics, and a
    record must never be refused for what its gap alone breaks. The fit reads such a
    segment as its contiguous pieces too. Pieces too short for a time series
    (``MIN_DYNAMIC``) are left out; the gap itself is :func:`check_timing`'s finding.
    """
    out: list[Segment] = []
    for s in segments:
        d = np.diff(s.t)
        if s.n < MIN_DYNAMIC or not s.dt_s > 0:
            out.append(s)
            continue
        breaks = np.flatnonzero(d > _GAP * s.dt_s) + 1
        if not breaks.size:
            out.append(s)
            continue
        bounds = [0, *breaks.tolist(), s.n]
        k = 0
        for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
            if hi - lo < MIN_DYNAMIC:
                continue
            k += 1
            piece = s.slice(lo, hi, label=f"{s.label}.{k}")
            # the commands before the gap did not drive this piece's start as recorded
            out.append(piece if lo == 0 else replace(piece, history_voltage=None))
    return tuple(out)


def check_timing(where: str, segments: Sequence[Segment]) -> list[Finding]:
    """Sample period, jitter and gaps of each time-series segment (tables are skipped)."""
    out: list[Finding] = []
    dyn = dynamic(segments)
    if not dyn:
        return out
    periods = np.array([s.dt_s for s in dyn])
    dt = float(np.median(periods))
    worst = 0.0
    n_jitter = n_int = 0
    for s in dyn:
        d = np.diff(s.t)
        med = s.dt_s
        rel = np.abs(d - med) / med
        gaps = d > _GAP * med
        n_int += int((~gaps).sum())
        n_jitter += int((rel[~gaps] > _JITTER_TOL).sum())
        worst = max(worst, float(rel[~gaps].max(initial=0.0)))
        if gaps.any():
            missing = int(np.sum(np.round(d[gaps] / med) - 1))
            out.append(
                Finding(
                    "gaps",
                    Severity.WARNING,
                    f"{where} [{s.label}]",
                    f"{int(gaps.sum())} gap(s) in the time column, about {missing} sample(s) "
                    f"missing (largest {_fmt_period(float(d.max()))} = "
                    f"{d.max() / med:.0f} periods at t = {s.t[int(np.argmax(d))]:.6g} s): the "
                    "fit takes the contiguous pieces between gaps, each from its own "
                    "initial state",
                    "record without dropped samples (a faster link or logger, a larger buffer)",
                    value=float(missing),
                    unit="samples",
                )
            )
    spread = float(periods.max() / periods.min() - 1.0)
    text = f"sample period {_fmt_period(dt)} ({1.0 / dt:.5g} Hz)"
    if spread > 0.01:
        text += f" (segments differ by up to {spread:.1%})"
    share = n_jitter / max(n_int, 1)
    out.append(
        Finding(
            "sample-period",
            Severity.INFO,
            where,
            f"{text}; {share:.1%} of the intervals off the median by > 5 % (worst {worst:.1%})",
            value=dt,
            unit="s",
        )
    )
    if share > 0.02:
        out.append(
            Finding(
                "jitter",
                Severity.WARNING,
                where,
                f"timestamps jitter: {share:.1%} of the intervals are off the median "
                f"{_fmt_period(dt)} by more than 5 % (worst {worst:.0%}); the fit simulates "
                "each segment on its median period",
                "log the driver's own sample time, not the time a sample arrived",
                value=share,
            )
        )
    return out


@memoised
def time_constants_s(segments: Sequence[Segment]) -> tuple[float | None, float | None]:
    """Electrical and mechanical time constants seen in the record, in ``t``'s units.

    From the per-sample poles of ``i[k+1] = a i[k] + b V[k] + c w[k] + d`` and
    ``w[k+1] = a w[k] + b V[k] + d`` over the driven samples; ``None`` when a
    pole is not resolved (settles within a sample, or no such signals).
    """
    tau_e: list[float] = []
    tau_m: list[float] = []
    for s in dynamic(segments):
        if s.voltage is None:
            continue
        driven = ~s.open_mask
        w = s.speed_or_derivative()
        if driven.sum() < 10 or np.ptp(w[driven]) == 0:
            continue
        v = np.where(driven, s.voltage, 0.0)
        # one held voltage (a step already on at the first sample): the constant carries it
        held = [] if np.ptp(s.voltage[driven]) == 0 else [v]
        if s.current is not None:
            a = arx_pole(s.current, [*held, w], driven)
            if a is not None and 0.0 < a < 1.0:
                tau_e.append(-s.dt_s / math.log(a))
        a = arx_pole(w, held, driven)
        if a is not None and 0.05 < a < 1.0:
            tau_m.append(-s.dt_s / math.log(a))
    med = lambda xs: float(np.median(xs)) if xs else None  # noqa: E731
    return med(tau_e), med(tau_m)


def check_time_unit(
    where: str, segments: Sequence[Segment], *, declared: bool = False
) -> tuple[list[Finding], float]:
    """ERROR when ``t`` cannot be seconds, and the factor to seconds of the unit it fixes.

    ``declared``: the user gave ``--time-unit``; then nothing is second-guessed.
    """
    dyn = dynamic(segments)
    if declared or not dyn:
        return [], 1.0
    dt = float(np.median([s.dt_s for s in dyn]))
    n = max(s.n for s in dyn)
    tau_e, tau_m = time_constants_s(dyn)
    reasons: list[str] = []
    if dt > DT_MAX_S and n > 50:
        hours = sum(s.duration_s for s in dyn) / 3600.0
        reasons.append(f"a sample every {dt:.4g} s over {n} samples ({hours:.3g} h)")
    if tau_e is not None and tau_e > TAU_E_MAX_S:
        reasons.append(f"the current settles with L/R = {tau_e:.3g} s")
    if tau_m is not None and tau_m > TAU_M_MAX_S:
        reasons.append(f"the speed settles with a time constant of {tau_m:.3g} s")
    if not reasons:
        return [], 1.0
    unit = None
    for name, f in _UNITS:
        ok_dt = 1e-5 <= dt * f <= 0.05
        ok_e = tau_e is None or tau_e * f <= TAU_E_MAX_S
        ok_m = tau_m is None or tau_m * f <= TAU_M_MAX_S
        if ok_dt and ok_e and ok_m:
            unit = name
            break
    t0 = float(segments[0].t[0])
    epoch = ""
    if t0 > 1e11:
        epoch = f" (t starts at {t0:.3g}: epoch {unit or 'sub-second units'}?)"
    flag = opt("time_unit")
    fix = f"{flag} {unit}" if unit else f"{flag} ms|us|ns (the unit of the t column)"
    finding = Finding(
        "time-unit",
        Severity.ERROR,
        where,
        f"t does not look like seconds: {'; '.join(reasons)}{epoch}"
        + (f"; in {unit} the period is {_fmt_period(dt * dict(_UNITS)[unit])}" if unit else "")
        + f" (pass {flag} s if it really is seconds)",
        fix,
        value=dt,
        unit="s",
    )
    return [finding], dict(_UNITS).get(unit or "", 1.0)
