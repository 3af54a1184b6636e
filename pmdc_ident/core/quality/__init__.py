"""The data-quality gate (ROS-free): checks over recorded runs -> one-line findings.

Names are imported on first use (PEP 562): the command line reads the finding
codes (``findings.CODES``) to check ``--ignore`` without importing numpy.
"""

from __future__ import annotations

from pmdc_ident._lazy import lazy_exports

_SOURCES: dict[str, str] = {
    "CODES": "findings",
    "Finding": "findings",
    "QualityReport": "findings",
    "Severity": "findings",
    "GateInput": "gate",
    "check_inputs": "gate",
}
__all__ = sorted(_SOURCES)
__getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
