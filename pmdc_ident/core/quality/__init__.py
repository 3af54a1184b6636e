"""The data-quality gate (ROS-free): checks over recorded runs -> one-line findings."""

from __future__ import annotations

from pmdc_ident.core.quality.findings import Finding, QualityReport, Severity
from pmdc_ident.core.quality.gate import GateInput, check_inputs

__all__ = ["Finding", "GateInput", "QualityReport", "Severity", "check_inputs"]
