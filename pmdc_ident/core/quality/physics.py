"""Physics checks: signs (swapped wires), power balance, command-to-response delay,
and the direction of rotation (one direction cannot separate Coulomb from a load).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.quality.findings import Finding, Severity
from pmdc_ident.core.quality.regress import (
    dynamic,
    electrical_fit,
    mechanical_fit,
    voltage_speed_response,
)

__all__ = [
    "check_current_filter",
    "check_delay",
    "check_direction",
    "check_power_balance",
    "noise_level",
]

_SURE = 6.0  # |coefficient / stderr| above which a sign counts as measured
_PRE = 6  # samples of constant command before an edge used for the delay estimate


def noise_level(x: np.ndarray) -> float:
    """Robust white-noise level of a signal from its second differences (MAD)."""
    if x.size < 4:
        return 0.0
    d2 = np.diff(x, 2)
    return float(np.median(np.abs(d2 - np.median(d2))) / 0.6745 / np.sqrt(6.0))


def check_power_balance(where: str, segments: Sequence[Segment]) -> list[Finding]:
    """Signs of R, Ke and Kt/J from the record; V*I against R*I^2 + Ke*w*I."""
    el = electrical_fit(segments)
    mech = mechanical_fit(segments, coulomb=False)
    out: list[Finding] = []
    neg = {
        name: fit.t(name) < -_SURE
        for fit, name in ((el, "R"), (el, "Ke"), (mech, "a"))
        if fit is not None
    }
    pos = {
        name: fit.t(name) > _SURE
        for fit, name in ((el, "R"), (el, "Ke"), (mech, "a"))
        if fit is not None
    }
    culprit = None
    if neg.get("R") and neg.get("a") and not neg.get("Ke"):
        culprit = "current"
    elif neg.get("Ke") and neg.get("a") and not neg.get("R"):
        culprit = "speed"
    elif neg.get("R") and neg.get("Ke") and not neg.get("a"):
        culprit = "voltage"
    elif neg.get("a") and el is None:
        culprit = "current or speed"
    elif neg.get("Ke") and pos.get("R") and mech is None:
        culprit = "speed"
    if culprit is not None:
        head = culprit.split()[0]
        out.append(
            Finding(
                "sign",
                Severity.ERROR,
                where,
                f"the {culprit} column has the wrong sign: "
                + ", ".join(
                    f"{k} {'< 0' if neg.get(k) else '> 0'}"
                    for k in ("R", "Ke", "a")
                    if k in neg or k in pos
                ).replace(" a ", " Kt/J ")
                + " from the record (a motor has R, Ke, Kt/J > 0): wires or sensor reversed",
                f"{opt('column')} {head}=-HEADER (flips its sign)",
            )
        )
        return out
    if el is None or not (pos.get("R") and pos.get("Ke")):
        return out
    r, ke, ind, off = el["R"], el["Ke"], el["L"], el["offset"]
    p_in, p_model = [], []
    for s in dynamic(segments):
        if s.voltage is None or s.current is None:
            continue
        dt = np.diff(s.t)
        w = s.speed_or_derivative()
        m = ~np.isnan(s.voltage[:-1])
        if el.quasi_static:  # the current settles within a sample: V[k] against i, w at k+1
            i1, w1 = s.current[1:], w[1:]
            p_in.append((s.voltage[:-1] * i1)[m])
            p_model.append(((r * i1 + ke * w1 + off) * i1)[m])
            continue
        ib = 0.5 * (s.current[1:] + s.current[:-1])
        wb = 0.5 * (w[1:] + w[:-1])
        p_in.append((s.voltage[:-1] * ib * dt)[m])
        p_model.append(((r * ib * dt + ind * np.diff(s.current) + (ke * wb + off) * dt) * ib)[m])
    pin = np.concatenate(p_in)
    gap = float(np.sqrt(np.mean((pin - np.concatenate(p_model)) ** 2)))
    scale = float(np.sqrt(np.mean(pin**2))) or 1.0
    sev = Severity.WARNING if gap > 0.2 * scale else Severity.INFO
    out.append(
        Finding(
            "power-balance",
            sev,
            where,
            f"V*I = R*I^2 + L*I*dI/dt + Ke*w*I to {gap / scale:.1%} rms with R = {r:.4g} "
            + (
                "ohm (the current settles within a sample: L*I*dI/dt left out)"
                if el.quasi_static
                else f"ohm, L = {ind:.3g} H"
            )
            + f", Ke = {ke:.4g} V*s/rad seen in the record"
            + (
                ": the voltage equation does not hold (voltage not at the armature? a drive "
                "that limits it? columns on different clocks?)"
                if sev is Severity.WARNING
                else ""
            ),
            "record the terminal voltage, or check the columns' time base"
            if sev is Severity.WARNING
            else "",
            value=gap / scale,
        )
    )
    return out


def _edge_responses(segments: Sequence[Segment]) -> list[tuple[int, float, float]]:
    """Per clean voltage edge: the current's lag (samples beyond the hold), and its first
    two increments once it responds (signed with the edge)."""
    out: list[tuple[int, float, float]] = []
    for s in dynamic(segments):
        if s.voltage is None or s.current is None:
            continue
        v = np.where(s.open_mask, np.nan, s.voltage)
        dv = np.abs(np.diff(v))
        span = float(np.nanmax(v) - np.nanmin(v)) if np.isfinite(v).any() else 0.0
        if span == 0:
            continue
        sigma = noise_level(s.current)
        edges = np.flatnonzero(dv > 0.2 * span) + 1
        for k in edges[:50]:
            lo = k - _PRE
            if lo < 0 or k + 12 > s.n or np.isnan(v[lo:k]).any() or np.ptp(v[lo:k]) > 0:
                continue
            base = float(np.median(s.current[lo:k]))
            moved = np.abs(s.current[lo : k + 12] - base) > 5 * sigma + 1e-12
            if moved.any() and not moved[:2].any():
                j = lo + int(np.argmax(moved))  # first sample that moved
                sign = float(np.sign(v[k] - v[k - 1]))
                i = s.current
                d1 = sign * (i[j] - i[j - 1]) if j + 1 < s.n else 0.0
                d2 = sign * (i[j + 1] - i[j]) if j + 1 < s.n else 0.0
                ok = d1 > 10 * sigma  # a first step well above the noise
                out.append((j - k - 1, d1 if ok else math.nan, d2 if ok else math.nan))
    return out


def check_delay(where: str, segments: Sequence[Segment]) -> list[Finding]:
    """Samples between a voltage edge and the current's first response (ZOH: one)."""
    responses = _edge_responses(segments)
    lags = [r[0] for r in responses]
    dt = [s.dt_s for s in dynamic(segments)]
    if len(lags) < 2:
        return []
    lag = int(np.median(lags))
    period = float(np.median(dt))
    if lag < 0:
        return [
            Finding(
                "delay",
                Severity.WARNING,
                where,
                f"the current changes {-lag} sample(s) before the voltage column does, at "
                f"{len(lags)} voltage edges: the voltage column is logged late",
                f"shift the voltage column {-lag} sample(s) earlier",
                value=float(lag),
                unit="samples",
            )
        ]
    if lag == 0:
        return [
            Finding(
                "delay",
                Severity.INFO,
                where,
                f"the current responds one sample after each of {len(lags)} voltage edges "
                "(no delay beyond the sample hold)",
                value=0.0,
                unit="samples",
            )
        ]
    return [
        Finding(
            "delay",
            Severity.WARNING,
            where,
            f"the current responds {lag} sample(s) ({lag * period * 1e3:.3g} ms) later than "
            f"the sample hold predicts after {len(lags)} voltage edges: a transport delay the "
            "linear fit does not model (it biases L and R)",
            f"shift the voltage column {lag} sample(s) later, or run `pmdc-ident diagnose` "
            "(effect 'delay')",
            value=float(lag),
            unit="samples",
        )
    ]


def check_current_filter(where: str, segments: Sequence[Segment]) -> list[Finding]:
    """A current that rises faster in its second sample than its first after a voltage step.

    An armature (R, L, back-EMF) answers a voltage step with its steepest slope at
    once: each increment is smaller than the one before. A sensor filter or a
    ramped drive voltage gives an S-shaped rise instead, which the fit would read
    as inductance.
    """
    ratios = [d2 / d1 for lag, d1, d2 in _edge_responses(segments) if lag == 0 and d1 > 0]
    if len(ratios) < 2:
        return []
    ratio = float(np.median(ratios))
    if ratio <= 1.1:
        return []
    return [
        Finding(
            "current-filter",
            Severity.WARNING,
            where,
            f"after {len(ratios)} voltage steps the current's second increment is {ratio:.2g} "
            "times its first (an armature's is at most 1): the current sensor filters, or the "
            "drive ramps the voltage; the fit reads that lag as inductance (L and R biased up)",
            "record the current before its filter (or the drive's unfiltered sense), or log "
            "the voltage the drive applies",
            value=ratio,
        )
    ]


def check_direction(where: str, segments: Sequence[Segment]) -> list[Finding]:
    """A note when the rotor turns one way only (Coulomb and a load torque are then one)."""
    w = np.concatenate([s.speed_or_derivative() for s in segments])
    big = np.abs(w) > 0.05 * float(np.max(np.abs(w)) or 1.0)
    if not big.any():
        return []
    pos = float(np.mean(w[big] > 0))
    if 0.02 < pos < 0.98:
        return []
    sense = "positive" if pos >= 0.98 else "negative"
    return [
        Finding(
            "one-direction",
            Severity.INFO,
            where,
            f"the rotor turns one way only (speed {sense}): Coulomb friction and a constant "
            "load torque act as one term here",
            "record both directions (a run in reverse separates them)",
        )
    ]


def check_no_current(where: str, segments: Sequence[Segment]) -> list[Finding]:
    """Voltage and speed without a current: only the response's gain and time constant."""
    dyn = [s for s in dynamic(segments) if s.voltage is not None and s.current is None]
    if not dyn or any(s.current is not None for s in segments):
        return []
    response = voltage_speed_response(dyn)
    what = ""
    if response is not None:
        what = (
            f" shows a gain of {response[0]:.4g} rad/s per V and a time constant of "
            f"{response[1] * 1e3:.3g} ms, i.e."
        )
    return [
        Finding(
            "no-current",
            Severity.WARNING,
            where,
            f"no current column: voltage -> speed alone{what} two combinations of R, Ke, J, "
            "B (with Kt = Ke: Ke/(R B + Ke^2) and R J/(R B + Ke^2)), not the parameters",
            "record the armature current (a shunt or the driver's current sense), or "
            f"{opt('fix')} R=... (multimeter) and {opt('fix')} B=... to read Ke and J from the "
            "two",
        )
    ]
