"""Findings of the data-quality gate: one line each, with the number measured and the fix."""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

__all__ = ["CODES", "Finding", "QualityReport", "Severity"]

# Every finding code the gate emits (``--ignore CODE`` accepts these).
CODES: tuple[str, ...] = (
    "check-failed",
    "clipping",
    "continuity",
    "current-filter",
    "current-missing",
    "current-unit",
    "delay",
    "duplicate",
    "encoder",
    "expected-rsd",
    "gaps",
    "identifiability",
    "jitter",
    "no-current",
    "no-drive",
    "no-excitation",
    "one-direction",
    "outlier",
    "position-unit",
    "position-wrap",
    "power-balance",
    "sample-period",
    "sign",
    "speed-counts",
    "speed-position",
    "speed-quantised",
    "speed-unit",
    "time-unit",
    "units",
    "voltage-missing",
    "voltage-unit",
)


class Severity(enum.Enum):
    """ERROR stops the fit (exit 2); WARNING is printed and kept; INFO is a measurement."""

    ERROR = "error"
    WARNING = "warning"
    INFO = "info"


@dataclass(frozen=True)
class Finding:
    """One check's outcome on one input (``where`` names the file and segment).

    ``value`` is the number measured (in ``unit``); ``fix`` what to pass or record
    instead (empty when there is nothing to do).
    """

    code: str
    severity: Severity
    where: str
    message: str
    fix: str = ""
    value: float | None = None
    unit: str = ""

    def __post_init__(self) -> None:
        if self.code not in CODES:  # a new check must be listed (and documented)
            msg = f"finding code {self.code!r} is not in quality.findings.CODES"
            raise ValueError(msg)

    def line(self) -> str:
        fix = f"; fix: {self.fix}" if self.fix else ""
        return f"{self.severity.value}: {self.code}: {self.where}: {self.message}{fix}"

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "code": self.code,
            "severity": self.severity.value,
            "where": self.where,
            "message": self.message,
        }
        if self.fix:
            out["fix"] = self.fix
        if self.value is not None and math.isfinite(self.value):
            out["value"] = float(self.value)
            out["unit"] = self.unit
        return out


@dataclass(frozen=True)
class QualityReport:
    """All findings of one gate run, most severe first."""

    findings: tuple[Finding, ...]
    expected_rsd: dict[str, float] = field(default_factory=dict)

    @classmethod
    def of(cls, findings: Iterable[Finding], expected_rsd: dict[str, float] | None = None):
        order = {Severity.ERROR: 0, Severity.WARNING: 1, Severity.INFO: 2}
        items = sorted(findings, key=lambda f: order[f.severity])
        return cls(tuple(items), dict(expected_rsd or {}))

    @property
    def errors(self) -> tuple[Finding, ...]:
        return tuple(f for f in self.findings if f.severity is Severity.ERROR)

    @property
    def warnings(self) -> tuple[Finding, ...]:
        return tuple(f for f in self.findings if f.severity is Severity.WARNING)

    @property
    def ok(self) -> bool:
        return not self.errors

    def downgraded(self, codes: Sequence[str]) -> QualityReport:
        """Errors whose code is in ``codes`` turned into warnings (``--ignore CODE``)."""
        wanted = set(codes)
        out = [
            replace(f, severity=Severity.WARNING, message=f"{f.message} (ignored by the user)")
            if f.severity is Severity.ERROR and f.code in wanted
            else f
            for f in self.findings
        ]
        return QualityReport.of(out, self.expected_rsd)

    def lines(self, *, info: bool = True) -> list[str]:
        return [f.line() for f in self.findings if info or f.severity is not Severity.INFO]

    def to_json(self) -> dict[str, Any]:
        return {
            "errors": len(self.errors),
            "warnings": len(self.warnings),
            "findings": [f.to_json() for f in self.findings],
            "expected_rsd": {
                k: float(v) for k, v in self.expected_rsd.items() if math.isfinite(v)
            },
        }
