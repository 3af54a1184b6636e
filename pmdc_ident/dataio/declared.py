"""Declared units checked against the data: a declaration another column contradicts is an error.

A unit the user states (``--speed-unit rpm``, a sidecar's ``speed_unit: rpm``) silences
the gate's magnitude checks on that signal. It must not also silence physics: when
the speed column and the position column describe one shaft, the speed is
d(position)/dt in consistent units, whatever the user declared. So, once the run is
converted, :func:`check_declared` measures that ratio; when it is not 1 and another
set of units explains it, the declaration is wrong and the command stops with the
units that agree (``--speed-unit rad/s``, not a guess such as counts per turn).
Likewise a duty cycle beyond its range (``duty`` is -1..1, ``duty%`` -100..100).

One rule for every declaration: the same function runs on CSV files and bags, for
units from the command line and from sidecars. A ratio no unit explains (a gear
between two sensors, a scaling in a logger) is left to the data-quality gate
(``speed-position``), which names it.
"""

from __future__ import annotations

import math
from itertools import product
from typing import TYPE_CHECKING

import numpy as np

from pmdc_ident.core.data import Run
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.errors import option_name as opt

if TYPE_CHECKING:
    from pmdc_ident.dataio.units import InputSpec

__all__ = ["check_declared"]

_TWO_PI = 2.0 * math.pi
_SPEED = {"rad/s": 1.0, "rpm": math.pi / 30.0, "deg/s": math.pi / 180.0, "rev/s": _TWO_PI}
_POSITION = {"rad": 1.0, "deg": math.pi / 180.0, "rev": _TWO_PI}
_TIME = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_AGREE = 0.05  # |ratio - 1| below this: the columns agree
_TOL = 0.03  # a unit set explains the ratio within this


def _factor(unit: str | None, table: dict[str, float], cpr: float | None) -> float | None:
    if unit is None:
        return 1.0
    base = unit.split("/")[0] if unit not in table else unit
    if unit.startswith("counts"):
        return None if cpr is None else _TWO_PI / cpr
    return table.get(unit, table.get(base, 1.0))


def _declared_factors(spec: InputSpec) -> tuple[float, float, float] | None:
    su = spec.speed_unit.value if spec.speed_unit else None
    pu = spec.position_unit.value if spec.position_unit else None
    tu = spec.time_unit.value if spec.time_unit else None
    fs = _factor(su, _SPEED, spec.counts_per_rev)
    fp = _factor(pu, _POSITION, spec.counts_per_rev)
    ft = _factor(tu, _TIME, None)
    if fs is None or fp is None or ft is None:
        return None
    return fs, fp, ft


def _options(spec: InputSpec, raw_ratio: float) -> list[str]:
    """The unit options under which the raw columns agree (fewest changes first)."""
    declared = {
        "time": spec.time_unit.value if spec.time_unit else "s",
        "speed": spec.speed_unit.value if spec.speed_unit else "rad/s",
        "position": spec.position_unit.value if spec.position_unit else "rad",
    }
    found: list[tuple[int, float, str]] = []
    for (tu, ft), (su, fs), (pu, fp) in product(_TIME.items(), _SPEED.items(), _POSITION.items()):
        miss = abs(raw_ratio * fs * ft / fp - 1.0)
        if miss >= _TOL:
            continue
        wanted = {"time": tu, "speed": su, "position": pu}
        changed = [k for k in wanted if wanted[k] != declared[k]]
        if not changed:
            continue
        words = " ".join(
            f"{opt(f'{k}_unit')} {wanted[k]}"
            for k in ("time", "speed", "position")
            if k in changed
        )
        found.append((len(changed), miss, words))
    # encoder counts: a speed in counts/s or a position in counts of a whole encoder
    if not found:
        for cpr, words in (
            (raw_ratio * _TWO_PI, f"{opt('speed_unit')} counts/s"),
            (_TWO_PI / raw_ratio, f"{opt('position_unit')} counts"),
        ):
            if cpr >= 16 and abs(cpr - round(cpr)) < 0.01 * cpr:
                found.append((1, 0.5, f"{words} {opt('counts_per_rev')} {round(cpr)}"))
    found.sort()
    return [w for n, _, w in found if n == found[0][0]][:2] if found else []


def _speed_position_ratio(run: Run) -> float | None:
    """Least-squares ratio of the speed column to d(position)/dt over the whole run."""
    num = den = 0.0
    for s in run.segments:
        if s.speed is None or s.position is None or s.n < 3:
            continue
        d_pos = np.diff(s.position)
        inc = 0.5 * (s.speed[1:] + s.speed[:-1]) * np.diff(s.t)
        # a wrap (position back by about a turn) is no motion
        keep = np.abs(d_pos) < 0.5 * max(float(np.ptp(s.position)), 1e-300)
        keep &= np.abs(np.diff(s.t) - s.dt_s) <= 0.25 * s.dt_s  # gaps are no interval
        if keep.sum() < 2:
            continue
        num += float(np.sum(inc[keep] * inc[keep]))
        den += float(np.sum(inc[keep] * d_pos[keep]))
    if den == 0.0 or num == 0.0 or not math.isfinite(num / den):
        return None
    return num / den


def check_declared(where: str, run: Run, spec: InputSpec, voltage_raw_max: float | None) -> None:
    """Refuse (:class:`DataError`, one line with the fix) a declared unit the data
    contradict. ``run`` is in SI units (converted with ``spec``); ``voltage_raw_max``
    is the largest |voltage| as the file holds it (None: no voltage column)."""
    from pmdc_ident.dataio.units import VoltageUnit

    if voltage_raw_max is not None and spec.voltage_unit in (
        VoltageUnit.DUTY,
        VoltageUnit.DUTY_PERCENT,
    ):
        limit = 1.0 if spec.voltage_unit is VoltageUnit.DUTY else 100.0
        if voltage_raw_max > limit * 1.001:
            other = (
                f"{opt('voltage_unit')} duty% (a percentage)"
                if spec.voltage_unit is VoltageUnit.DUTY and voltage_raw_max <= 100.0
                else f"{opt('voltage_unit')} V (volts)"
            )
            msg = (
                f"{where}: {opt('voltage_unit')} {spec.voltage_unit.value} (from {spec.origin}) "
                f"contradicts the voltage column: it reaches {voltage_raw_max:.4g}, beyond "
                f"a duty cycle's {limit:g}; fix: {other}"
            )
            raise DataError(msg)
    if not ({"speed", "position", "time"} & spec.declared()):
        return
    factors = _declared_factors(spec)
    ratio = _speed_position_ratio(run)
    if factors is None or ratio is None or abs(ratio - 1.0) < _AGREE:
        return
    fs, fp, ft = factors
    raw = ratio * fp / (fs * ft)  # the ratio of the columns as written in the file
    options = _options(spec, raw)
    if not options:
        return  # no unit explains it: the gate's speed-position check names it
    given = " ".join(
        f"{opt(f'{k}_unit')} {getattr(spec, f'{k}_unit').value}"
        for k in ("time", "speed", "position")
        if getattr(spec, f"{k}_unit") is not None
    )
    msg = (
        f"{where}: {given} (from {spec.origin}) contradicts the other columns: with it "
        f"speed = {ratio:.5g} x d(position)/dt, where one shaft gives 1; the columns agree "
        f"with {' or '.join(options)}; fix: {options[0]}"
    )
    raise DataError(msg)
