"""Sim-to-real gap diagnosis (issue 6), ROS-free.

Given recorded runs, :func:`diagnose` fits the seeds' linear model on part of
the segments (the *fit* set), measures its free-run simulation error on the
rest (the *held-out* set), localizes that gap by signal and regime, fits every
effect of the vocabulary (docs/design.md §4) (and combinations) on the fit set, scores
them on the held-out set with a penalty per added parameter, and returns a
verdict: ``no_gap``, ``explained`` by named effects, or ``unexplained``.
"""

from __future__ import annotations

from pmdc_ident.core.diagnosis.config import DiagnosisConfig
from pmdc_ident.core.diagnosis.pipeline import diagnose
from pmdc_ident.core.diagnosis.results import (
    CandidateScore,
    DiagnosisResult,
    Tie,
    Verdict,
    VerdictStatus,
)
from pmdc_ident.core.diagnosis.verdict import Thresholds

__all__ = [
    "CandidateScore",
    "DiagnosisConfig",
    "DiagnosisResult",
    "Thresholds",
    "Tie",
    "Verdict",
    "VerdictStatus",
    "diagnose",
]
