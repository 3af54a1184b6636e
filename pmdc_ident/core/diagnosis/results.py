"""Result objects of the diagnosis and their JSON form (keys of docs/design.md §4)."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any

from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis.holdout import HoldoutSplit
from pmdc_ident.core.diagnosis.localization import Localization
from pmdc_ident.core.identification.estimate import ParameterEstimate, finite_or_none
from pmdc_ident.core.params import PARAMETER_NAMES

__all__ = [
    "CandidateScore",
    "DiagnosisResult",
    "RegimeShrink",
    "Tie",
    "Verdict",
    "VerdictStatus",
]


class VerdictStatus(enum.Enum):
    NO_GAP = "no_gap"
    EXPLAINED = "explained"
    UNEXPLAINED = "unexplained"


@dataclass(frozen=True)
class CandidateScore:
    """One candidate model (baseline + effects) scored on the held-out segments."""

    effects: tuple[str, ...]
    gap: float  # held-out gap of the candidate
    shrink: float  # 1 - gap / baseline gap
    added_parameters: int
    penalized_gap: float  # gap + penalty per added parameter
    significant: bool  # improvement beats the penalty
    parameters: dict[str, float] = field(default_factory=dict)  # effect parameters
    fit_seconds: float = 0.0

    def to_json(self) -> dict[str, object]:
        return {
            "effects": list(self.effects),
            "gap": finite_or_none(self.gap),
            "shrink": finite_or_none(self.shrink),
            "added_parameters": self.added_parameters,
            "penalized_gap": finite_or_none(self.penalized_gap),
            "significant": self.significant,
            "parameters": self.parameters,
        }


@dataclass(frozen=True)
class Tie:
    """Effects the data cannot tell apart, and the test that would."""

    effects: tuple[str, ...]
    separating_test: str

    def to_json(self) -> dict[str, object]:
        return {"effects": list(self.effects), "separating_test": self.separating_test}


@dataclass(frozen=True)
class Verdict:
    status: VerdictStatus
    effects: tuple[str, ...]
    ties: tuple[Tie, ...]
    message: str

    def to_json(self) -> dict[str, object]:
        return {
            "status": self.status.value,
            "effects": list(self.effects),
            "ties": [t.to_json() for t in self.ties],
            "message": self.message,
        }


@dataclass(frozen=True)
class RegimeShrink:
    category: str
    label: str
    sample_share: float
    gap_before: float
    gap_after: float

    @property
    def shrink(self) -> float:
        return 1.0 - self.gap_after / self.gap_before if self.gap_before > 0 else math.nan

    def to_json(self) -> dict[str, object]:
        return {
            "category": self.category,
            "label": self.label,
            "sample_share": round(self.sample_share, 4),
            "gap_before": finite_or_none(self.gap_before),
            "gap_after": finite_or_none(self.gap_after),
            "shrink": finite_or_none(self.shrink),
        }


_UNITS = {"current": "A", "speed": "rad/s"}


def _ratio(a: float, b: float) -> float:
    return a / b if b > 0 and math.isfinite(b) else math.nan


def _g(x: object) -> str:
    return "-" if x is None else f"{float(x):.3g}"  # type: ignore[arg-type]


def _pct(x: object) -> str:
    return "-" if x is None else f"{float(x):.2g} %"  # type: ignore[arg-type]


def _signal_rms(segments: tuple[Segment, ...], signal: str) -> float:
    """RMS of a measured signal over the held-out segments (speed: the column, else the
    position's derivative, as the diagnosis compares it)."""
    import numpy as np

    parts = [
        s.current if signal == "current" else s.speed_or_derivative()
        for s in segments
        if signal != "current" or s.current is not None
    ]
    parts = [p for p in parts if p is not None and p.size]
    if not parts:
        return math.nan
    x = np.concatenate(parts)
    return float(np.sqrt(np.mean(x[np.isfinite(x)] ** 2)))


@dataclass(frozen=True)
class DiagnosisResult:
    """Everything the diagnosis found; ``to_json`` gives the keys of docs/design.md §4."""

    verdict: Verdict
    split: HoldoutSplit
    gap_before: float
    gap_after: float
    gap_by_signal_before: dict[str, float]
    gap_by_signal_after: dict[str, float]
    rms_before: dict[str, float]
    rms_after: dict[str, float]
    noise_sigma: dict[str, float]
    localization: Localization
    candidates: tuple[CandidateScore, ...]  # ranked, best first
    baseline: tuple[ParameterEstimate, ...]
    augmented: tuple[ParameterEstimate, ...]  # baseline + verdict effects
    regimes: tuple[RegimeShrink, ...]
    assumptions: tuple[str, ...]
    elapsed_s: float
    n_samples: int
    # For plots (not in the JSON): held-out segments, and the baseline's and the
    # augmented model's free-run predictions on them (objects with current, speed).
    held_out: tuple[Segment, ...] = field(default=(), repr=False, compare=False)
    predictions_before: tuple[object, ...] = field(default=(), repr=False, compare=False)
    predictions_after: tuple[object, ...] = field(default=(), repr=False, compare=False)
    # per effect, the smallest size this record could have shown (core.diagnosis.detection)
    detection_limits: tuple[Any, ...] = ()

    @property
    def shrink(self) -> float:
        if self.gap_before <= 0:
            return 0.0
        return min(1.0, 1.0 - max(self.gap_after, 0.0) / self.gap_before)

    def to_json(self) -> dict[str, object]:
        return {
            "verdict": self.verdict.to_json(),
            "holdout": {
                **self.split.to_json(),
                "gap_before": finite_or_none(max(self.gap_before, 0.0)),
                "gap_after": finite_or_none(max(self.gap_after, 0.0)),
                "shrink": finite_or_none(self.shrink),
                "gap_by_signal_before": self.gap_by_signal_before,
                "gap_by_signal_after": self.gap_by_signal_after,
                "rms_error_before": self.rms_before,
                "rms_error_after": self.rms_after,
                "by_signal": self.gap_in_units(),
                "noise_sigma": self.noise_sigma,
                "gap_definition": (
                    "held-out mean squared simulation error minus the noise variance, "
                    "in noise variances, averaged over current and speed"
                ),
                "regimes": [r.to_json() for r in self.regimes],
            },
            "localization": self.localization.to_json(),
            "candidates": [c.to_json() for c in self.candidates],
            "baseline": {p.name: p.to_json() for p in self.baseline},
            "parameters": {p.name: p.to_json() for p in self.augmented},
            "assumptions": list(self.assumptions),
            "detection_limits": {d.effect: d.to_json() for d in self.detection_limits},
            "elapsed_s": round(self.elapsed_s, 3),
            "n_samples": self.n_samples,
        }

    def gap_in_units(self) -> dict[str, dict[str, object]]:
        """Per signal, the held-out error in units people read: RMS before and after in the
        signal's unit, as a percentage of the held-out signal's own RMS, and as a ratio to
        the noise (1 = the model misses nothing the sensor could show)."""
        out: dict[str, dict[str, object]] = {}
        for sig, before in self.rms_before.items():
            after = self.rms_after.get(sig, math.nan)
            noise = self.noise_sigma.get(sig, math.nan)
            level = _signal_rms(self.held_out, sig)
            out[sig] = {
                "unit": _UNITS.get(sig, ""),
                "rms_error_before": finite_or_none(before),
                "rms_error_after": finite_or_none(after),
                "signal_rms": finite_or_none(level),
                "percent_of_signal_before": finite_or_none(100.0 * _ratio(before, level)),
                "percent_of_signal_after": finite_or_none(100.0 * _ratio(after, level)),
                "noise_sd": finite_or_none(noise),
                "times_noise_before": finite_or_none(_ratio(before, noise)),
                "times_noise_after": finite_or_none(_ratio(after, noise)),
            }
        return out

    def summary_lines(self) -> list[str]:
        """A short human summary (published by the node, printed by ``make demo``)."""
        v = self.verdict
        lines = [
            f"verdict: {v.status.value}" + (f" ({', '.join(v.effects)})" if v.effects else "")
        ]
        lines.append(v.message)
        lines.append(
            f"free-run error on held-out data, before -> after ({self.shrink:.0%} of the "
            f"excess closed; split: {self.split.rule}):"
        )
        for sig, g in self.gap_in_units().items():
            lines.append(
                f"  {sig}: RMS {_g(g['rms_error_before'])} -> {_g(g['rms_error_after'])} "
                f"{g['unit']} = {_pct(g['percent_of_signal_before'])} -> "
                f"{_pct(g['percent_of_signal_after'])} of its RMS {_g(g['signal_rms'])} "
                f"{g['unit']}, {_g(g['times_noise_before'])} -> {_g(g['times_noise_after'])} "
                f"x the noise ({_g(g['noise_sd'])} {g['unit']})"
            )
        lines += [f"  {s}" for s in self.localization.sentences[:4]]
        for t in v.ties:
            lines.append(f"tie: {' / '.join(t.effects)}; to separate: {t.separating_test}")
        top = [c for c in self.candidates if c.significant][:3]
        if top:
            lines.append(
                "candidates: " + "; ".join(f"{'+'.join(c.effects)} {c.shrink:.0%}" for c in top)
            )
        names = [p for p in self.augmented if p.name not in PARAMETER_NAMES]
        for p in names:
            ci = f" [{p.ci95[0]:.3g}, {p.ci95[1]:.3g}]" if p.ci95 else ""
            lines.append(f"  {p.name} = {p.value:.4g}{ci} {p.unit}")
        if self.detection_limits:
            lines.append("smallest sizes this record could show (detection limits):")
            lines += [f"  {d.text()}" for d in self.detection_limits]
        return lines
