"""What to change after an abort, ROS-free: the parameter that would have let the
session go on, named with its value, for the abort's log line and ``status``."""

from __future__ import annotations

from pmdc_ident.core.enums import AbortReason
from pmdc_ident.core.safety import SafetyConfig

__all__ = ["abort_remedy"]


def abort_remedy(
    reason: AbortReason,
    safety: SafetyConfig,
    peer_timeout_s: float,
    *,
    late_s: float | None = None,
    command_delay_s: float | None = None,
) -> str:
    """The parameter to raise (or lower) after an abort for ``reason`` ('' when a
    parameter is not the fix: Ctrl-C, a driver fault). For a joint that left its travel
    range, ``late_s`` is how late driver samples reached the node just before (a command
    sent on them left at least that late) and ``command_delay_s`` how late a command may
    be with the plan still keeping the joint inside."""
    if reason is AbortReason.OUT_OF_TRAVEL and late_s is not None and command_delay_s is not None:
        return _travel_remedy(late_s, command_delay_s)
    if reason is AbortReason.LOST_DRIVER_DATA:
        return (
            f"on a busy machine raise safety.data_timeout_s (now {safety.data_timeout_s:g} s; "
            "session.launch.py: data_timeout_s:=...)"
        )
    if reason is AbortReason.PEER_CRASHED:
        return f"if the recorder is only slow, raise peer_timeout_s (now {peer_timeout_s:g} s)"
    if reason is AbortReason.OVER_CURRENT:
        return (
            f"lower voltage_max_v, or raise safety.current_max_a (now "
            f"{safety.current_max_a:.4g} A) up to the driver's current_limit_a"
        )
    if reason is AbortReason.OVER_SPEED:
        return (
            f"lower voltage_max_v, or raise safety.speed_max_rad_s (now "
            f"{safety.speed_max_rad_s:.4g} rad/s) up to the driver's speed_limit_rad_s"
        )
    if reason is AbortReason.STALL:
        return (
            f"if the rotor does turn, raise safety.stall_time_s (now {safety.stall_time_s:.3g} "
            f"s) or safety.stall_current_a (now {safety.stall_current_a:.3g} A)"
        )
    return ""


def _travel_remedy(late_s: float, command_delay_s: float) -> str:
    if late_s > command_delay_s:
        return (
            f"driver samples reached this node up to {late_s:.2f} s late just before, "
            f"beyond the {command_delay_s:.3g} s the plan keeps the joint inside for: on a "
            f"busy host raise plan_command_delay_s (now {command_delay_s:g} s) to "
            f"{late_s:.2g} s or more (slower plans, that may aim lower), or give the node more CPU"
        )
    return (
        f"commands were on time (samples at most {late_s:.2f} s late, the plan allows "
        f"{command_delay_s:.3g} s): check plan_travel_rad and the motor file the plan was "
        "designed from against the joint"
    )
