"""Unit slips in scale: speed against d(position)/dt, and magnitudes no motor log has.

The speed/position check is physics (both columns describe one shaft): the
ratio of the speed column to the position's derivative is 1 in consistent units,
and a known ratio names the slip (30/pi: rpm; 180/pi: deg/s; cpr/2 pi: counts).
A current or voltage column scaled by 1000 is an exact record of another motor
(R, L, Kt scaled with it), so magnitude is the only clue there: a check fires
only when the magnitude is far beyond motor practice, and the user can always
declare the unit to silence it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.quality.findings import Finding, Severity
from pmdc_ident.core.quality.regress import dynamic
from pmdc_ident.core.quality.signals import find_wrap

__all__ = ["check_magnitudes", "check_speed_position", "speed_position_ratio"]

_TWO_PI = 2.0 * math.pi
# SI factor of each unit the column may really be in (rad/s or rad per unit).
_SPEED = {"rad/s": 1.0, "rpm": math.pi / 30.0, "deg/s": math.pi / 180.0, "rev/s": _TWO_PI}
_POSITION = {"rad": 1.0, "deg": math.pi / 180.0, "rev": _TWO_PI}
_TIME = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_TOL = 0.03  # relative agreement that counts as "explained by this unit"


def speed_position_ratio(segments: Sequence[Segment]) -> float | None:
    """Least-squares ratio of the speed column to d(position)/dt (trapezoid increments)."""
    num = den = 0.0
    for s in dynamic(segments):
        if s.speed is None or s.position is None:
            continue
        d_pos = np.diff(s.position)
        wrap = find_wrap(s.position)
        keep = np.ones(d_pos.size, dtype=bool)
        if wrap is not None:
            keep = np.abs(d_pos) < 0.5 * wrap[0]
        # a gap (a paused logger, a clock jump) is no sample interval: 1000 s of it
        # outweighed the whole record and read as a time unit (fix: --time-unit us)
        keep &= np.abs(np.diff(s.t) - s.dt_s) <= 0.25 * s.dt_s
        inc = 0.5 * (s.speed[1:] + s.speed[:-1]) * np.diff(s.t)
        num += float(np.sum(inc[keep] * inc[keep]))
        den += float(np.sum(inc[keep] * d_pos[keep]))
    if den == 0.0 or num == 0.0:
        return None
    return num / den


def _explanations(ratio: float) -> list[str]:
    out: list[tuple[int, float, str]] = []
    for tu, ft in _TIME.items():
        for su, fs in _SPEED.items():
            for pu, fp in _POSITION.items():
                predicted = fp / (fs * ft)
                miss = abs(ratio / predicted - 1.0)
                if miss < _TOL and (tu, su, pu) != ("s", "rad/s", "rad"):
                    slips = (
                        [f"{opt('time_unit')} {tu}"] * (tu != "s")
                        + [f"{opt('speed_unit')} {su}"] * (su != "rad/s")
                        + [f"{opt('position_unit')} {pu}"] * (pu != "rad")
                    )
                    out.append((len(slips), miss, " ".join(slips)))
    # encoder counts: speed in counts/s (ratio = cpr / 2 pi) or position in counts (2 pi / cpr)
    counts = (
        (ratio * _TWO_PI, f"{opt('speed_unit')} counts/s"),
        (_TWO_PI / ratio, f"{opt('position_unit')} counts"),
    )
    for cpr, fix in () if out else counts:
        if cpr >= 16 and abs(cpr - round(cpr)) < 0.01 * cpr:
            out.append((1, 0.5, f"{fix} {opt('counts_per_rev')} {round(cpr)}"))
    out.sort()
    return [text for k, _, text in out[:2] if k == out[0][0]]


def check_speed_position(
    where: str, segments: Sequence[Segment], *, declared: bool = False
) -> list[Finding]:
    """ERROR when the speed column is not d(position)/dt in the same angle unit."""
    ratio = speed_position_ratio(segments)
    if ratio is None:
        return []
    if abs(ratio - 1.0) < 0.05:
        return [
            Finding(
                "speed-position",
                Severity.INFO,
                where,
                f"speed = {ratio:.4f} x d(position)/dt: the two columns agree",
                value=ratio,
            )
        ]
    fixes = _explanations(ratio)
    sev = Severity.ERROR if fixes and not declared else Severity.WARNING
    why = (
        "the columns are in different units"
        if fixes
        else "no unit explains it (a gear between the two sensors? a scaling in the logger?)"
    )
    return [
        Finding(
            "speed-position",
            sev,
            where,
            f"speed = {ratio:.5g} x d(position)/dt: {why}",
            " or ".join(fixes)
            if fixes
            else f"{opt('gear_ratio')} N or the right {opt('speed_unit')}",
            value=ratio,
        )
    ]


# Current plausibility (issue 22: a 48 V, 0.05 ohm traction motor draws 205 A): a motor's
# current grows with its voltage class, and no brushed motor at <= 60 V has a winding
# whose stall current V/R is beyond STALL_MAX_A. A current column in mA of a small motor
# reads as hundreds of "A" with a "winding" of a few milliohm.
CURRENT_PER_12V_A = 200.0
STALL_MAX_A = 2500.0


def current_ceiling_a(v_max: float) -> float:
    """The 95th-percentile current above which amperes are doubted at ``v_max`` volts."""
    return CURRENT_PER_12V_A * max(1.0, v_max / 12.0)


def stall_plausible(stall_a: float | None) -> bool:
    """A stall current V/R some brushed motor has (unknown R: not plausible)."""
    return stall_a is not None and 0.0 < stall_a <= STALL_MAX_A


_STALL_FIT_SAMPLES = 250_000  # R from the voltage equation needs no more (a long record)
_STALL_WINDOW = 5_000


def _spread_windows(segments: Sequence[Segment]) -> list[Segment]:
    """``segments``, or for a long record windows spread evenly over each of them, at most
    :data:`_STALL_FIT_SAMPLES` samples in all (the regression over every sample of a
    3.7 M-row log held 1 GB for one resistance)."""
    total = sum(s.n for s in segments)
    if total <= _STALL_FIT_SAMPLES:
        return list(segments)
    out: list[Segment] = []
    for s in segments:
        share = max(1, round(_STALL_FIT_SAMPLES * s.n / total / _STALL_WINDOW))
        if s.n <= share * _STALL_WINDOW:
            out.append(s)
            continue
        starts = np.linspace(0, s.n - _STALL_WINDOW, share).round().astype(int)
        out += [_window(s, int(a), int(a) + _STALL_WINDOW) for a in starts]
    return out


def _window(s: Segment, a: int, b: int) -> Segment:
    """Samples ``a:b`` of ``s`` as views, no history (``Segment.slice`` sums the record
    before ``a`` into one; the voltage equation reads samples alone)."""
    from dataclasses import replace

    names = ("t", "voltage", "current", "position", "speed", "terminal_voltage")
    views = {n: (None if getattr(s, n) is None else getattr(s, n)[a:b]) for n in names}
    return replace(
        s, history_voltage=None, history_heat_a2s=None, history_heat_profile=None, **views
    )


def _stall_current(segments: Sequence[Segment], v_max: float) -> float | None:
    """``v_max / R`` with R from the record's own voltage equation, when it is measured."""
    from pmdc_ident.core.quality.regress import electrical_fit

    el = electrical_fit(_spread_windows(segments))
    if el is None or not el["R"] > 0 or el.t("R") < 6.0:
        return None
    return v_max / el["R"]


def check_magnitudes(
    where: str, segments: Sequence[Segment], declared: frozenset[str]
) -> list[Finding]:
    """Voltages and currents far beyond any motor log (mV, mA, duty cycles, rpm)."""
    dyn = dynamic(segments) or list(segments)
    out: list[Finding] = []
    volts = [s.voltage[~s.open_mask] for s in dyn if s.voltage is not None]
    v = np.abs(np.concatenate(volts)) if volts else np.zeros(0)
    v_max = float(v.max()) if v.size else 0.0
    cur = [s.current for s in dyn if s.current is not None]
    w = np.abs(np.concatenate([s.speed_or_derivative() for s in dyn]))
    moving = float(w.max()) > 0
    if "voltage" not in declared and v_max > 1000.0:
        out.append(
            Finding(
                "voltage-unit",
                Severity.ERROR,
                where,
                f"voltage reaches {v_max:.5g} V: millivolts? (in mV that is {v_max / 1e3:.4g} V; "
                f"pass {opt('voltage_unit')} V if it really is volts)",
                f"{opt('voltage_unit')} mV",
                value=v_max,
                unit="V",
            )
        )
    if "voltage" not in declared and 0.0 < v_max <= 1.0 and moving:
        out.append(
            Finding(
                "voltage-unit",
                Severity.WARNING,
                where,
                f"voltage never exceeds {v_max:.3g} V while the rotor turns: a duty cycle?",
                f"{opt('voltage_unit')} duty {opt('supply_v')} V (or {opt('voltage_unit')} V to "
                "keep volts)",
                value=v_max,
                unit="V",
            )
        )
    if cur and "current" not in declared:
        i = np.abs(np.concatenate(cur))
        p95 = float(np.percentile(i, 95))
        integers = bool(np.all(i == np.round(i))) and float(np.ptp(i)) >= 20.0
        doubted = v_max <= 60.0 and p95 > current_ceiling_a(v_max)
        # the record's own resistance only where the amperes are in doubt (a regression)
        stall = _stall_current(segments, v_max) if doubted else None
        big = doubted and not stall_plausible(stall)
        if big or (v_max <= 60.0 and integers and p95 >= 20.0):
            hint = " in whole numbers" if integers else ""
            why = (
                f", and the record's own winding resistance ({v_max / stall:.3g} ohm) makes "
                f"its stall current {stall:.3g} A"
                if stall is not None and not integers
                else ""
            )
            out.append(
                Finding(
                    "current-unit",
                    Severity.ERROR,
                    where,
                    f"current reaches {p95:.5g} A (95th percentile){hint} at no more than "
                    f"{v_max:.3g} V{why}: milliamps? (pass {opt('current_unit')} A if it really "
                    "is amperes)",
                    f"{opt('current_unit')} mA",
                    value=p95,
                    unit="A",
                )
            )
    has_position = any(s.position is not None for s in dyn)
    w_max = float(w.max())
    if "speed" not in declared and not has_position and w_max > 3000.0:
        # an error like the current and voltage magnitudes (a speed 9.5x or 57x too high
        # gave Ke -90 % / -98 %); rpm and deg/s both fit and nothing here tells them apart
        out.append(
            Finding(
                "speed-unit",
                Severity.ERROR,
                where,
                f"speed reaches {w_max:.5g} rad/s ({w_max * 30 / math.pi:.3g} rpm): beyond "
                "any motor in rad/s; without a position column the data cannot tell rpm "
                f"from deg/s (pass {opt('speed_unit')} rad/s if it really is rad/s)",
                f"{opt('speed_unit')} rpm or {opt('speed_unit')} deg/s (whichever the logger "
                "wrote)",
                value=w_max,
                unit="rad/s",
            )
        )
    return out
