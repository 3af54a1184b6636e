"""What a gate warning means for the fit's result: parameters the record biases, flagged.

The gate measures some defects of a record that the motor model has no term for:
a filtered current sensor (an S-shaped rise after each voltage step) or a
transport delay between the voltage column and the current. The fit then reads
the lag as inductance and returns a tight interval around a wrong L (a 2 ms RC
filter on a motor with L/R = 1 ms: L came out 2.1x the truth, ci95 +-2 %). Such a
parameter is marked not identifiable in the result, its reason naming the
finding and its fix; the other parameters keep their values (R, Ke and J moved
by 1.3 %, 0.01 % and 2.6 % on that record) and a warning says which were checked.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import replace

from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.identification.estimate import ParameterEstimate
from pmdc_ident.core.quality.findings import Finding, Severity

__all__ = ["BIASED_BY", "flag_biased"]

# finding code -> the parameters whose fitted value absorbs what it measured
BIASED_BY: dict[str, tuple[str, ...]] = {
    "current-filter": ("L",),
    "delay": ("L",),
}
_WHAT = {
    "current-filter": "the current sensor filters (or the drive ramps the voltage)",
    "delay": "the current lags the voltage column by more than the sample hold",
}


def flag_biased(
    parameters: Mapping[str, ParameterEstimate],
    findings: Iterable[Finding],
    fixed: Mapping[str, float] | None = None,
) -> tuple[dict[str, ParameterEstimate], str | None]:
    """``parameters`` with each one a warning in ``findings`` biases marked not
    identifiable (a value the user fixed is left alone), and the warning that says
    which (None when none)."""
    params = dict(parameters)
    said: list[str] = []
    for f in findings:
        if f.severity is not Severity.WARNING:
            continue
        for name in BIASED_BY.get(f.code, ()):
            p = params.get(name)
            if p is None or name in (fixed or {}) or not p.identifiable:
                continue
            fix = f"; {f.fix}" if f.fix else ""
            params[name] = replace(
                p,
                identifiable=False,
                ci95=None,
                reason=f"{_WHAT[f.code]} (gate: {f.code}): the fit reads that lag as "
                f"{name}{fix}, or {opt('fix')} {name}=... from an LCR meter",
                notes=frozenset(),
            )
            said.append(f"{name} ({f.code})")
    if not said:
        return params, None
    warning = (
        f"not identifiable because the record's sensor or timing biases it: {', '.join(said)}; "
        "the value written is the fit's, the interval withheld"
    )
    return params, warning
