"""The data-quality gate: every check over every input, before any fit.

:func:`check_inputs` takes the runs already in SI units (``dataio.units``) and
returns a :class:`QualityReport`; errors stop ``identify``/``diagnose`` with exit
status 2, warnings are printed and kept in the JSON under ``quality``.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from pmdc_ident.core.assumptions import data_findings
from pmdc_ident.core.data import Run, Segment, excitation_problem
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.quality.findings import Finding, QualityReport, Severity
from pmdc_ident.core.quality.physics import (
    check_current_filter,
    check_delay,
    check_direction,
    check_no_current,
    check_power_balance,
)
from pmdc_ident.core.quality.regress import memo
from pmdc_ident.core.quality.scales import check_magnitudes, check_speed_position
from pmdc_ident.core.quality.signals import (
    check_clipping,
    check_columns,
    check_quantisation,
    check_wrap,
)
from pmdc_ident.core.quality.timing import check_time_unit, check_timing, cut_at_gaps

__all__ = ["GateInput", "check_inputs"]


@dataclass(frozen=True)
class GateInput:
    """One DATA argument in SI units, with the signals whose unit the user declared."""

    name: str
    run: Run
    declared: frozenset[str] = frozenset()
    notes: tuple[str, ...] = ()


def _fingerprint(run: Run) -> str:
    """Hash of the samples (time left out: a re-export shifted in time is the same data)."""
    h = hashlib.blake2b(digest_size=16)
    for s in run.segments:
        for name in ("voltage", "current", "position", "speed"):
            arr = getattr(s, name)
            h.update(name.encode())
            if arr is not None:
                h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()


def _duplicates(inputs: Sequence[GateInput]) -> list[Finding]:
    seen: dict[str, str] = {}
    out: list[Finding] = []
    for x in inputs:
        key = _fingerprint(x.run)
        if key in seen:
            same_path = seen[key] == x.name
            what = "passed twice" if same_path else f"holds the same samples as {seen[key]}"
            out.append(
                Finding(
                    "duplicate",
                    Severity.ERROR,
                    x.name,
                    f"{what}: counting one recording twice shrinks every interval by sqrt(2)",
                    "pass each recording once",
                )
            )
        else:
            seen[key] = x.name
    return out


def _per_input(x: GateInput) -> list[Finding]:
    segs: tuple[Segment, ...] = x.run.segments
    d = x.declared
    out = [Finding("units", Severity.INFO, x.name, note) for note in x.notes]
    # every check but the timing's reads the pieces between gaps in time: none compares a
    # sample with one the gap separates it from (cut_at_gaps)
    pieces = cut_at_gaps(segs)
    time_unit, factor = check_time_unit(x.name, pieces, declared="time" in d)
    out += time_unit
    # the speed/position check in the time unit the gate suggests (else it blames the speed)
    in_s = pieces if factor == 1.0 else tuple(replace(s, t=s.t * factor) for s in pieces)
    checks: list[Callable[[], list[Finding]]] = [
        lambda: check_timing(x.name, segs),
        lambda: check_columns(x.name, pieces),
        lambda: check_magnitudes(x.name, pieces, d),
        lambda: check_speed_position(x.name, in_s, declared=bool({"speed", "position"} & d)),
        lambda: check_quantisation(x.name, pieces, position_declared="position" in d),
        lambda: check_clipping(x.name, pieces),
        lambda: check_power_balance(x.name, pieces),
        lambda: check_delay(x.name, pieces),
        lambda: check_current_filter(x.name, pieces),
        lambda: check_no_current(x.name, pieces),
    ]
    for seg in pieces:
        checks.append(lambda seg=seg: check_wrap(x.name, seg, position_declared="position" in d))
    checks.append(lambda: data_findings(x.name, x.run))  # the assumption register's
    for check in checks:
        out += _guarded(check, x.name)
    return out


def _guarded(check: Callable[[], list[Finding]], where: str) -> list[Finding]:
    """A check that fails on data nobody foresaw says so; it never stops the others."""
    try:
        return check()
    except (ArithmeticError, ValueError, IndexError, np.linalg.LinAlgError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else ""
        return [
            Finding(
                "check-failed",
                Severity.WARNING,
                where,
                f"a check could not run on these data ({type(exc).__name__}: {first[:80]}); "
                "the others did",
            )
        ]


def _excitation(names: str, segs: list[Segment], found: list[Finding]) -> list[Finding]:
    """identify's and diagnose's own no-excitation rule, so check agrees with them."""
    if any(f.code == "no-drive" for f in found):  # the same record, already said
        return []
    problem = excitation_problem(segs)
    if problem is None:
        return []
    what, fix = problem
    return [Finding("no-excitation", Severity.ERROR, names, what, fix)]


def check_inputs(
    inputs: Sequence[GateInput],
    *,
    fixed: Mapping[str, float] | None = None,
    ignore: Sequence[str] = (),
) -> QualityReport:
    """All findings over ``inputs`` (each a file already converted to SI units).

    ``fixed``: parameters the fit will hold (``--fix``), left out of the
    expected-uncertainty estimate. ``ignore``: error codes the user overrides
    (``--ignore CODE``); they become warnings and do not stop the expected
    uncertainties from being computed.
    """
    with memo():
        return _check_inputs(inputs, fixed, frozenset(ignore)).downgraded(ignore)


def _check_inputs(
    inputs: Sequence[GateInput], fixed: Mapping[str, float] | None, ignore: frozenset[str]
) -> QualityReport:
    findings: list[Finding] = []
    findings += _duplicates(inputs)
    for x in inputs:
        findings += _per_input(x)
    segs = [s for x in inputs for s in x.run.segments]
    pieces = [p for x in inputs for p in cut_at_gaps(x.run.segments)]  # as the fit reads them
    if segs:
        names = ", ".join(x.name for x in inputs)
        findings += check_direction(names, pieces) if pieces else []
        has_v = [s for s in segs if s.voltage is not None]
        if has_v and all(s.open_mask.all() for s in has_v) and len(has_v) == len(segs):
            findings.append(
                Finding(
                    "no-drive",
                    Severity.ERROR,
                    names,
                    "the voltage is empty in every row of every input: all of it is an "
                    "open-armature coast, which tells B/J and the friction over J but not "
                    "R, L, Ke or J itself",
                    f"record the voltage command (or {opt('column')} voltage=HEADER for its "
                    "column), "
                    "or add a driven run",
                )
            )
        findings += _excitation(names, segs, findings)
    rsd: dict[str, float] = {}
    if pieces and not any(f.severity is Severity.ERROR and f.code not in ignore for f in findings):
        from pmdc_ident.core.quality.information import information_findings

        def information() -> list[Finding]:
            more, expected = information_findings(names, pieces, fixed or {})
            rsd.update(expected)
            return more

        findings += _guarded(information, names)
    return QualityReport.of(findings, rsd)
