"""ROS-free motor backends: the simulated plant and the serial board."""

from __future__ import annotations

from pmdc_ident.backends.base import Backend, BackendError, Telemetry

__all__ = ["Backend", "BackendError", "Telemetry"]
