"""Misfit-robust checks: what a Cramer-Rao interval cannot see (issue 22).

An interval from the fit's covariance is true only when the model is. When the
residuals are not white, the model misses something, and a parameter can sit
150 times off with a +-3 % interval (a coreless motor at 500 Hz whose drive ramps
its voltage: L = 0.17 H for a nominal 1.16 mH). Then every free parameter must also
pass checks that do not trust the model, before it is reported identified
(register entries ``run-start``, ``parts-agree``, ``electrical-resolution``):

1. **the start**: where a run starts with the rotor measured at rest, the start the
   fit estimated must agree with the first samples (no initial speed the sensor
   contradicts, no current of the wrong sign). When it does not, the fit is repeated
   without each such run's first stretch; a parameter that then moves beyond its
   interval, or has no information left, rested on a start the data contradict;
2. **disjoint parts**: the model refitted on two disjoint parts of the data (the
   segments alternately, or the halves of a single segment), and led by each signal
   (the current, the speed); a parameter both identify must agree within 3 combined
   standard errors (each fit's own, widened for its coloured residuals);
3. **the electrical time constant**: with non-white current residuals, an L/R below
   the sample period rests on the first sample after each voltage step, exactly
   where unmodelled sensor or drive dynamics sit.

Each failure is a :class:`Flag`: the parameter, the register entry and the reason
with what to record. The refits are ``refit(segments)`` of the caller (the same
model, fixed values and closure).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.estimators.output_error import FitResult
from pmdc_ident.core.model import Model

__all__ = ["AGREE_SIGMAS", "Flag", "Misfit", "Refit", "misfit_flags"]

AGREE_SIGMAS = 3.0  # parts (or the fit without the start) agree within this many se
APART_REL = 0.2  # ... or within this share of the value (then the interval covers both)
START_SIGMAS = 4.0  # an estimated start agrees with the first samples within this many
NOT_IDENTIFIED = 0.5  # relative standard error above which a part does not identify it
_HEAD = 5  # first samples that show the rotor at rest
COVER_REL = 0.1  # a refit's value enters the interval when it identifies it this well


@dataclass(frozen=True)
class Flag:
    """A parameter that failed a misfit-robust check (``code``: the register id)."""

    name: str
    code: str
    reason: str


Cover = dict[str, list[tuple[float, float]]]  # per parameter, the refits' 95 % ranges


class Refit(Protocol):
    """The chosen model fitted on ``segments`` with the caller's fixed values and
    closure (``weights`` per signal, more ``fixed`` values, another ``model``)."""

    def __call__(
        self,
        segments: Sequence[Segment],
        *,
        weights: Mapping[str, float] | None = None,
        fixed: Mapping[str, float] | None = None,
        model: Model | None = None,
    ) -> FitResult: ...


def _noise(x: np.ndarray) -> float:
    if x.size < 8:
        return 0.0
    d2 = np.diff(x, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def _quantum(x: np.ndarray) -> float:
    d = np.abs(np.diff(x))
    d = d[d > 0]
    return float(d.min()) if d.size and np.unique(x).size < 0.5 * x.size else 0.0


def _apart(a: float, b: float, se: float) -> bool:
    """Two estimates of one parameter that cannot both hold: more than ``AGREE_SIGMAS``
    combined standard errors apart *and* more than ``APART_REL`` of their size. A
    smaller significant difference widens the interval instead (the refits are
    covered, :func:`_collect`)."""
    scale = max(abs(a), abs(b))
    return abs(a - b) > AGREE_SIGMAS * se and abs(a - b) > APART_REL * scale


def _se(fit: FitResult, name: str, widen: float) -> float:
    se = fit.stderr.get(name)
    return math.inf if se is None or not math.isfinite(se) else se * widen


def _rel(fit: FitResult, name: str, widen: float) -> float:
    v = abs(fit.values.get(name, math.nan))
    return _se(fit, name, widen) / v if v > 0 else math.inf


def _widen(fit: FitResult, segs: Sequence[Segment]) -> float:
    from pmdc_ident.core.estimators.uncertainty import coloured_noise_factor

    try:
        factors = coloured_noise_factor(fit, segs)
    except (PmdcError, ValueError, ArithmeticError):
        return 1.0
    return math.sqrt(max([1.0, *factors.values()]))


# ---------------------------------------------------------------------------
# 1. the start
# ---------------------------------------------------------------------------
def _contradicted_start(fit: FitResult, seg: Segment) -> str | None:
    """What the fit's estimated start of ``seg`` says against its first samples, or
    None when they agree (or the rotor is not measured at rest there)."""
    from pmdc_ident.core.assumptions import continues

    x0 = fit.initial_states.get(seg.label)
    if x0 is None or continues(seg) or seg.n < 4 * _HEAD:
        return None
    speed = seg.speed if seg.speed is not None else None
    if speed is not None:
        sd, q = _noise(speed), _quantum(speed)
        head = speed[:_HEAD]
    else:
        assert seg.position is not None
        pos = seg.position
        sd, q = _noise(np.diff(pos)) / seg.dt_s, _quantum(pos) / seg.dt_s
        head = np.diff(pos[: _HEAD + 1]) / seg.dt_s
    tol_w = START_SIGMAS * sd + q + 1e-12
    if float(np.max(np.abs(head))) > tol_w:
        return None  # the rotor already turns: nothing measured to hold the start to
    said = []
    if abs(x0[1]) > tol_w:
        said.append(f"w0 = {x0[1]:.4g} rad/s against a measured rest (noise {sd + q:.2g})")
    if seg.current is not None and seg.voltage is not None and np.isfinite(seg.voltage[0]):
        i_meas = float(seg.current[0])
        sd_i = _noise(seg.current)
        tol_i = START_SIGMAS * sd_i + 1e-12
        wrong_sign = x0[0] * float(seg.voltage[0]) < 0 and abs(x0[0]) > tol_i
        if wrong_sign or abs(x0[0] - i_meas) > tol_i + 0.05 * float(np.max(np.abs(seg.current))):
            said.append(f"i0 = {x0[0]:.4g} A against a measured {i_meas:.4g} A (noise {sd_i:.2g})")
    if not said:
        return None
    return f"{seg.label}: " + ", ".join(said)


def _start_flags(
    fit: FitResult, dyn: Sequence[Segment], refit: Refit, widen: float, cover: Cover
) -> list[Flag]:
    bad = {s.label: why for s in dyn if (why := _contradicted_start(fit, s)) is not None}
    if not bad:
        return []
    cut = [s.slice(max(_HEAD, s.n // 10), s.n) if s.label in bad else s for s in dyn]
    try:
        other = refit(cut)
    except PmdcError:
        return []
    w2 = _widen(other, cut)
    _collect(cover, fit, other, w2)
    where = "; ".join(bad.values())
    out = []
    for name in fit.free:
        if not fit.identifiable.get(name, True):
            continue
        a, b = fit.values[name], other.values.get(name, math.nan)
        se = math.hypot(_se(fit, name, widen), _se(other, name, w2))
        lost = _rel(other, name, w2) > NOT_IDENTIFIED
        if not (lost or _apart(a, b, se)):
            continue
        what = (
            "has no information left without it"
            if lost
            else f"is {b:.4g} without it ({AGREE_SIGMAS:g} standard errors off)"
        )
        out.append(
            Flag(
                name,
                "run-start",
                f"rests on a start the first samples contradict (estimated {where}); {name} "
                f"{what}: the record's first response is not this model's (a drive that "
                "ramps its voltage, a sensor's filter or delay); "
                f"{_record(name)}",
            )
        )
    return out


# ---------------------------------------------------------------------------
# 2. disjoint parts
# ---------------------------------------------------------------------------
def _parts(dyn: Sequence[Segment]) -> tuple[list[Segment], list[Segment], str] | None:
    if len(dyn) >= 2:
        a = [s for k, s in enumerate(dyn) if k % 2 == 0]
        b = [s for k, s in enumerate(dyn) if k % 2 == 1]
        return a, b, "the segments taken alternately"
    (s,) = dyn
    if s.n < 80:
        return None
    half = s.n // 2
    return [s.slice(0, half)], [s.slice(half, s.n)], "the two halves of the record"


def _parts_flags(fit: FitResult, dyn: Sequence[Segment], refit: Refit, cover: Cover) -> list[Flag]:
    from pmdc_ident.core.data import excitation_problem

    parts = _parts(dyn)
    if parts is None:
        return []
    a, b, how = parts
    if excitation_problem(a) is not None or excitation_problem(b) is not None:
        return []
    try:
        fa, fb = refit(a), refit(b)
    except PmdcError:
        return []
    wa, wb = _widen(fa, a), _widen(fb, b)

    def why(name: str, va: float, vb: float, z: float) -> str:
        return (
            f"the data disagree with themselves under this model: {name} = {va:.4g} and "
            f"{vb:.4g} on {how} ({z:.1f} combined standard errors apart, the residuals not "
            f"white); {_RECORD.get(name, _RECORD['*'])}"
        )

    return _pair_flags(fit, (fa, wa), (fb, wb), why, cover)


def _pair_flags(
    fit: FitResult,
    first: tuple[FitResult, float],
    second: tuple[FitResult, float],
    why: Callable[[str, float, float, float], str],
    cover: Cover,
) -> list[Flag]:
    """Two refits (each with its widening) compared parameter by parameter: the ones
    both identify and that lie apart (:func:`_apart`) are flagged, ``why`` the reason;
    both refits enter the cover."""
    (fa, wa), (fb, wb) = first, second
    _collect(cover, fit, fa, wa)
    _collect(cover, fit, fb, wb)
    out = []
    for name in fit.free:
        if not fit.identifiable.get(name, True):
            continue
        if _rel(fa, name, wa) > NOT_IDENTIFIED or _rel(fb, name, wb) > NOT_IDENTIFIED:
            continue  # a refit that cannot see it cannot contradict it
        va, vb = fa.values[name], fb.values[name]
        se = math.hypot(_se(fa, name, wa), _se(fb, name, wb))
        if _apart(va, vb, se):
            out.append(Flag(name, "parts-agree", why(name, va, vb, abs(va - vb) / se)))
    return out


# ---------------------------------------------------------------------------
# 2b. the signals: the current and the speed tell one motor
# ---------------------------------------------------------------------------
_FAINT = 0.03  # weight of the signal a one-signal-led fit leaves (almost) aside


def _signals_flags(
    fit: FitResult, dyn: Sequence[Segment], refit: Refit, cover: Cover
) -> list[Flag]:
    """The model fitted led by the current, and led by the speed (the other signal
    weighted ``_FAINT``): a parameter both identify must agree. A filtered current
    sensor on a fast armature reads as a larger L from the current, while the speed
    answers the torque of the unfiltered current."""
    mech = "speed" if all(s.speed is not None for s in dyn) else "position"
    if any(s.current is None or s.voltage is None for s in dyn):
        return []
    try:
        fi = refit(dyn, weights={mech: _FAINT})
        fw = refit(dyn, weights={"current": _FAINT})
    except PmdcError:
        return []
    wi, ww = _widen(fi, dyn), _widen(fw, dyn)

    def why(name: str, a: float, b: float, z: float) -> str:
        return (
            f"the current and the {mech} tell different motors: {name} = {a:.4g} led by "
            f"the current, {b:.4g} led by the {mech} ({z:.1f} combined standard errors "
            "apart; a sensor's filter or lag, or a drive that shapes its voltage); "
            f"{_record(name)}"
        )

    return _pair_flags(fit, (fi, wi), (fw, ww), why, cover)


# ---------------------------------------------------------------------------
# 3. the electrical time constant
# ---------------------------------------------------------------------------
def _electrical_flags(
    fit: FitResult, dyn: Sequence[Segment], white: Mapping[str, bool]
) -> list[Flag]:
    from pmdc_ident.core.quality.information import HARDWARE_MAX_HZ, _hz

    if "L" not in fit.free or white.get("current", True) or not fit.identifiable.get("L", True):
        return []
    dt = min(s.dt_s for s in dyn)
    tau = fit.values["L"] / fit.values["R"]
    if not tau < dt:
        return []
    need = 10.0 / tau
    rate = (
        f"sample at >= {_hz(need)} (10 samples per L/R) or fix L from an LCR meter "
        f"({opt('fix')} L=...)"
        if need <= HARDWARE_MAX_HZ
        else f"fix L from an LCR meter ({opt('fix')} L=...): resolving it needs a rate beyond a "
        "drive's current sensing"
    )
    return [
        Flag(
            "L",
            "electrical-resolution",
            f"L/R = {tau * 1e3:.3g} ms is below the sample period {dt * 1e3:.3g} ms, so L "
            "shows only in the current's first sample after each voltage step, and the "
            "current residuals are not white: a sensor's filter, a delay or a drive's ramp "
            f"there would read as inductance; {rate}",
        )
    ]


_RECORD = {
    "L": "record the current before any filter and the voltage the drive applies (terminal "
    "voltage), or fix L from an LCR meter ({fix} L=...)",
    "R": "record a locked-rotor step or measure R with a multimeter ({fix} R=...)",
    "Ke": "record steady speeds at several voltages (a staircase)",
    "J": "record a coast-down with the armature open, or add a known inertia ({added_inertia})",
    "B": "record steady speeds at several voltages in both directions",
    "*": "run `pmdc-ident diagnose` for the effect the model misses",
}


def _record(name: str) -> str:
    """What to record for ``name``, the options in the caller's words."""
    text = _RECORD.get(name, _RECORD["*"])
    return text.format(fix=opt("fix"), added_inertia=opt("added_inertia"))


def _collect(cover: Cover, fit: FitResult, other: FitResult, widen: float) -> None:
    """The 95 % range of each parameter ``other`` (a refit) identifies well (relative
    standard error within 10 %: a weak refit would only blur the interval)."""
    for name in fit.free:
        if name in other.values and _rel(other, name, widen) <= COVER_REL:
            v, se = other.values[name], _se(other, name, widen)
            cover.setdefault(name, []).append((v - 1.96 * se, v + 1.96 * se))


@dataclass(frozen=True)
class Misfit:
    """The flags, and per parameter the 95 % ranges of the refits that identify it (an
    interval that survives the wrong model covers them all)."""

    flags: tuple[Flag, ...]
    cover: dict[str, list[tuple[float, float]]]


def misfit_flags(
    fit: FitResult,
    dyn: Sequence[Segment],
    refit: Refit,
    *,
    white: Mapping[str, bool],
    widen: float,
) -> Misfit:
    """Every free parameter's misfit-robust checks (none when the residuals are white);
    one flag per parameter (the first check it fails)."""
    cover: Cover = {}
    if all(white.values()):
        return Misfit((), cover)
    flags = _electrical_flags(fit, dyn, white)
    flags += _start_flags(fit, dyn, refit, widen, cover)
    flags += _parts_flags(fit, dyn, refit, cover)
    flags += _signals_flags(fit, dyn, refit, cover)
    out: dict[str, Flag] = {}
    for f in flags:
        out.setdefault(f.name, f)
    return Misfit(tuple(out.values()), cover)
