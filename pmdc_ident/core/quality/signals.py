"""Per-signal checks: position wrap, quantisation (encoder counts per turn), clipping,
and columns that were not really recorded (all empty, all zero).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.quality.findings import Finding, Severity
from pmdc_ident.core.quality.regress import dynamic
from pmdc_ident.core.quantisation import quantum, record_steps

__all__ = [
    "check_clipping",
    "check_columns",
    "check_quantisation",
    "check_wrap",
    "find_wrap",
    "quantum",  # (from core.quantisation, the one rule)
]

FloatArray = NDArray[np.float64]
_TWO_PI = 2.0 * math.pi
# position wrap periods: what they mean when the column was read as radians
_WRAP_UNITS = ((_TWO_PI, "rad"), (360.0, "deg"), (1.0, "rev"))


def find_wrap(position: FloatArray) -> tuple[float, int] | None:
    """``(period, count)`` when ``position`` jumps back by one period as it turns, else None.

    A wrap is a step at least half the column's range, at least 20 times the 90th
    percentile of the other steps and at least 4 of the column's smallest steps (an
    encoder's count), against the direction of motion. Without the last rule a shaft
    that stood still but for one count back (a slow crawl at rest on a 4800-count
    encoder: a range of one count) read as wrapping with a period of one count.
    """
    d = np.diff(position)
    if d.size < 10:
        return None
    span = float(np.ptp(position))
    ad = np.abs(d)
    small = float(np.percentile(ad, 90))
    moved = ad[ad > 0]
    count = float(moved.min()) if moved.size else 0.0
    jumps = ad > max(0.5 * span, 20.0 * small, 4.0 * count)
    if span <= 0 or not jumps.any() or jumps.sum() > 0.2 * d.size:
        return None
    motion = float(np.median(d[~jumps])) if (~jumps).any() else 0.0
    period = float(np.median(np.abs(d[jumps] - motion)))
    return period, int(jumps.sum())


def check_wrap(where: str, seg: Segment, *, position_declared: bool = False) -> list[Finding]:
    """A position that still wraps after conversion (its period says the unit)."""
    if seg.position is None or seg.n < 20:
        return []
    found = find_wrap(seg.position)
    if found is None:
        return []
    period, count = found
    unit = next((u for p, u in _WRAP_UNITS if abs(period / p - 1.0) < 0.02), None)
    cpr = round(period)
    if unit is None and period > 8 and abs(period - cpr) < 0.02 * period:
        unit = "counts"
    if unit == "rad":
        return []  # the reader unwraps 2 pi wraps itself (a note says so)
    fixes = {
        "deg": f"{opt('position_unit')} deg",
        "rev": f"{opt('position_unit')} rev",
        "counts": f"{opt('position_unit')} counts {opt('counts_per_rev')} {cpr}",
    }
    sev = Severity.WARNING if position_declared else Severity.ERROR
    text = f"position wraps {count} time(s) with a period of {period:.6g}"
    if unit is not None and not position_declared:
        text += f" ({'one turn in ' + unit})"
    return [
        Finding(
            "position-wrap",
            sev,
            f"{where} [{seg.label}]",
            text + ": as radians the shaft would jump back by that much",
            fixes.get(unit or "", "give the position unwrapped, or in rad/deg/rev/counts"),
            value=period,
        )
    ]


def check_quantisation(
    where: str, segments: Sequence[Segment], *, position_declared: bool = False
) -> list[Finding]:
    """Encoder counts per turn from the position's step; a step that is no encoder in rad.

    The steps come from :func:`core.quantisation.record_steps`, the rule the fit's
    noise model uses too.
    """
    steps = record_steps(dynamic(segments), ("speed", "position"))
    out: list[Finding] = []
    if "position" in steps:
        out += _position_quantum(where, steps["position"].step, position_declared)
    if "speed" in steps:
        q = steps["speed"]
        out.append(
            Finding(
                "speed-quantised",
                Severity.INFO,
                where,
                f"speed moves in steps of {q.step:.4g} rad/s ({q.levels} levels): its "
                "noise is at least the step / sqrt(12)",
                value=q.step,
                unit="rad/s",
            )
        )
        out += _speed_counts(where, dynamic(segments), q.step)
    return out


def _speed_counts(where: str, segments: Sequence[Segment], step: float) -> list[Finding]:
    """A speed in whole encoder counts per sample without a position column: the counts
    since the last sample, i.e. the mean over the interval, not the speed at the sample."""
    if not segments or any(s.position is not None for s in segments):
        return []
    dt = float(np.median([s.dt_s for s in segments]))
    counts = _TWO_PI / (step * dt)
    n = round(counts)
    if not (1 <= n <= 10000 and abs(counts - n) <= max(0.02, 2e-4 * n)):
        return []
    return [
        Finding(
            "speed-counts",
            Severity.ERROR,
            where,
            f"speed moves in whole counts per sample ({step:.4g} rad/s x {dt * 1e3:.4g} ms = "
            f"one count of a {n}-count encoder): a speed made of the counts since the last "
            "sample is their mean over the interval, half a sample behind the speed the fit "
            "compares it with (a 50 Hz PRBS read so: R +55 %, L x50, J -12 %)",
            f"{opt('speed_averaged')} (the fit then takes the counts' running sum as the "
            f"encoder's position), or {opt('ignore')} speed-counts if the sensor samples the "
            "speed",
            value=float(n),
            unit="counts/rev",
        )
    ]


def _position_quantum(where: str, step: float, declared: bool) -> list[Finding]:
    cpr = _TWO_PI / step
    whole = abs(cpr - round(cpr)) <= 1e-3 * cpr
    alternatives = []
    if abs(step - 1.0) < 1e-6:
        alternatives.append(f"{opt('position_unit')} counts {opt('counts_per_rev')} N")
    for scale, unit in ((360.0, "deg"), (1.0, "rev")):
        c = scale / step
        if c >= 4 and abs(c - round(c)) <= 1e-3 * c:
            alternatives.append(f"{opt('position_unit')} {unit} (then {round(c)} counts/rev)")
    if whole or declared or not alternatives:
        odd = "" if whole else " (not a whole number: a gear between encoder and shaft?)"
        return [
            Finding(
                "encoder",
                Severity.INFO,
                where,
                f"position moves in steps of {step:.6g} rad: an encoder of "
                f"{cpr:.6g} counts/rev{odd} (its noise, step / sqrt(12), enters the noise model)",
                value=cpr,
                unit="counts/rev",
            )
        ]
    return [
        Finding(
            "position-unit",
            Severity.ERROR,
            where,
            f"position moves in steps of {step:.6g}: as radians that is {cpr:.5g} counts per "
            f"turn, which no encoder has (pass {opt('position_unit')} rad if it really is "
            "radians)",
            " or ".join(alternatives),
            value=step,
        )
    ]


def _pile_up(x: FloatArray, other: FloatArray | None) -> tuple[float, int] | None:
    """``(level, count)`` of a pile-up at the signal's max or min |value| (a rail)."""
    if x.size < 100:
        return None
    for level in (float(x.max()), float(x.min())):
        at = x == level
        count = int(at.sum())
        if count < max(5, 0.002 * x.size) or level == 0.0:
            continue
        values, counts = np.unique(x, return_counts=True)
        if values.size < 50:
            return None  # coarsely quantised: repeated levels are normal
        k = int(np.searchsorted(values, level))
        near = counts[max(k - 5, 0) : k] if level == values[-1] else counts[k + 1 : k + 6]
        if near.size and count < 5 * float(near.mean()):
            continue
        if other is not None and float(np.ptp(other[at])) <= 1e-9 * max(float(np.ptp(other)), 1):
            continue  # everything constant there: a steady state, not a rail
        return level, count
    return None


def check_clipping(where: str, segments: Sequence[Segment]) -> list[Finding]:
    """Measured signals that pile up at one extreme value while the others still move."""
    dyn = dynamic(segments)
    out: list[Finding] = []
    for name, other in (
        ("current", "speed"),
        ("speed", "current"),
        ("terminal_voltage", "current"),
    ):
        arrs = [getattr(s, name) for s in dyn if getattr(s, name) is not None]
        if not arrs:
            continue
        x = np.concatenate(arrs)
        o = [
            getattr(s, other) if getattr(s, other) is not None else s.speed_or_derivative()
            for s in dyn
            if getattr(s, name) is not None
        ]
        found = _pile_up(x, np.concatenate(o))
        if found is None:
            continue
        level, count = found
        out.append(
            Finding(
                "clipping",
                Severity.WARNING,
                where,
                f"{name} sits at {level:.6g} in {count} samples ({count / x.size:.1%}) while "
                f"the {other} still changes: a sensor or the drive saturates there, and the "
                "clipped samples bias the fit",
                "keep the test inside the sensor's range (lower voltage steps) or widen it",
                value=level,
            )
        )
    return out


def check_columns(where: str, segments: Sequence[Segment]) -> list[Finding]:
    """Columns that exist but hold nothing: current all zero, voltage all zero."""
    dyn = dynamic(segments) or list(segments)
    out: list[Finding] = []
    w = np.concatenate([s.speed_or_derivative() for s in dyn])
    moving = float(np.max(np.abs(w))) > 0 and float(np.ptp(w)) > 0
    volts = [s.voltage[~s.open_mask] for s in dyn if s.voltage is not None]
    v = np.concatenate(volts) if volts else np.zeros(0)
    cur = [s.current[~s.open_mask] for s in dyn if s.current is not None]
    i = np.concatenate(cur) if cur else None
    if i is not None and i.size and float(np.max(np.abs(i))) == 0.0 and v.size and moving:
        out.append(
            Finding(
                "current-missing",
                Severity.ERROR,
                where,
                f"current is 0 in every driven row while the voltage reaches "
                f"{float(np.max(np.abs(v))):.4g} V and the rotor turns: the current sensor "
                "was not recorded",
                f"record the current, or drop the column: {opt('column')} current=none",
            )
        )
    if v.size and float(np.max(np.abs(v))) == 0.0 and moving and i is not None and i.any():
        out.append(
            Finding(
                "voltage-missing",
                Severity.ERROR,
                where,
                "voltage is 0 in every driven row while current flows and the rotor turns: "
                "the command was not recorded",
                f"record the voltage command (or {opt('column')} voltage=HEADER for its column)",
            )
        )
    return out
