"""The driver's backend from its parameters (ROS-free): which backend, with which
limits, sensors and safe mode."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from pmdc_ident.backends.base import Backend
from pmdc_ident.core.enums import SafeMode
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.motors import Limits, MotorSpec, SensorSpec

__all__ = ["BackendConfigError", "make_backend"]


class BackendConfigError(PmdcError):
    """A driver parameter is invalid or the backend cannot be started (one line)."""


def _override(value: float, default: float) -> float:
    return default if value < 0 else float(value)


def make_backend(
    cfg: Mapping[str, Any],
    spec: MotorSpec,
    limits: Limits,
    log: Callable[[str], None],
) -> Backend:
    """The backend the driver's parameters ``cfg`` name (see the driver's parameter
    table): ``sim`` with the motor file's sensors unless overridden, or ``serial``.

    ``limits`` are the trips the backend applies itself on every sample (as board
    firmware does), whatever the host's timing.
    """
    dt_s = 1.0 / float(cfg["rate_hz"])
    safe_mode = SafeMode(cfg["safe_mode"])
    if cfg["backend"] == "sim":
        from pmdc_ident.backends.sim import SimBackend

        s = spec.sensors
        sensors = SensorSpec(
            current_noise_a=_override(cfg["current_noise_a"], s.current_noise_a),
            speed_noise_rad_s=_override(cfg["speed_noise_rad_s"], s.speed_noise_rad_s),
            encoder_counts_per_rev=_override(
                cfg["encoder_counts_per_rev"], s.encoder_counts_per_rev
            ),
        )
        return SimBackend(
            spec, dt_s, sensors=sensors, limits=limits, safe_mode=safe_mode, seed=int(cfg["seed"])
        )
    try:
        from pmdc_ident.backends.serial_board import SerialBackend
    except ImportError as exc:
        msg = f"backend 'serial' is not available ({exc})"
        raise BackendConfigError(msg) from None
    try:
        # The host's link timeout and the board's own watchdog tolerate the stall the
        # driver's watchdog tolerates (a busy machine raises it: see the demo); the board
        # keeps its 500 ms where the driver's is off.
        watchdog_s = float(cfg["watchdog_s"])
        timeout = max(100.0 * dt_s, 0.5, watchdog_s)
        board_ms = min(65535, max(20, round(watchdog_s * 1000))) if watchdog_s > 0 else 500
        return SerialBackend(
            cfg["port"],
            int(cfg["baud"]),
            limits,
            dt_s,
            safe_mode,
            log,
            telemetry_timeout_s=timeout,
            board_watchdog_ms=board_ms,
            timeout_name="raise the driver's watchdog_s",
        )
    except (OSError, PmdcError) as exc:
        msg = f"cannot open the driver board on {cfg['port']}: {exc}"
        raise BackendConfigError(msg) from None
