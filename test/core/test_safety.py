"""The one safety monitor (core/safety.py) as the driver and the session use it."""

from __future__ import annotations

import math

import pytest

from pmdc_ident.core.enums import AbortReason, Fault
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.safety import SafetyConfig, SafetyMonitor

DT = 1e-3


def _driver_monitor(watchdog_s: float = 0.5) -> SafetyMonitor:
    """As the driver node builds it: no stall rule, non-finite readings ignored."""
    return SafetyMonitor(
        SafetyConfig(
            current_max_a=10.0,
            speed_max_rad_s=100.0,
            watchdog_s=watchdog_s,
            non_finite_trips=False,
        )
    )


def test_over_current_and_over_speed_trip_once_and_latch_until_reset():
    mon = _driver_monitor()
    assert mon.check(0.0, 9.9, 99.0) is None
    assert mon.check(0.1, -10.5, 0.0) is AbortReason.OVER_CURRENT
    assert "over-current" in mon.message()
    assert mon.check(0.2, -11.0, 0.0) is None  # already latched
    assert mon.check(0.3, 0.0, 120.0) is AbortReason.OVER_SPEED
    assert mon.tripped and mon.faults == Fault.OVER_CURRENT | Fault.OVER_SPEED
    assert mon.reason is AbortReason.OVER_CURRENT  # the first trip is the reason
    mon.reset()
    assert not mon.tripped and mon.faults == Fault.NONE and mon.message() == ""


def test_infinite_limit_disables_a_trip():
    mon = SafetyMonitor(
        SafetyConfig(current_max_a=math.inf, speed_max_rad_s=math.inf, non_finite_trips=False)
    )
    assert mon.check(0.0, 1e6, 1e6) is None
    assert not mon.watchdog_expired(1e9, driving=True)  # watchdog_s 0: off


def test_non_finite_readings_trip_the_session_but_not_the_driver():
    session = SafetyMonitor(SafetyConfig(current_max_a=10.0, speed_max_rad_s=100.0))
    assert session.check(0.0, math.nan, 0.0) is AbortReason.DRIVER_FAULT
    assert _driver_monitor().check(0.0, math.nan, 0.0) is None


def test_limits_change_at_run_time_and_are_checked():
    mon = _driver_monitor()
    mon.update(current_max_a=20.0)
    assert mon.check(0.0, 15.0, 0.0) is None
    with pytest.raises(ParameterError, match="current_max_a"):
        mon.update(current_max_a=-1.0)


def test_watchdog_fires_once_after_the_timeout_and_a_command_clears_it():
    mon = _driver_monitor(watchdog_s=0.5)
    mon.command_received(10.0)
    assert not mon.watchdog_expired(10.49, driving=True)
    assert mon.watchdog_expired(10.51, driving=True)
    assert not mon.watchdog_expired(10.6, driving=True)  # once
    assert mon.faults == Fault.WATCHDOG
    mon.command_received(11.0)
    assert mon.faults == Fault.NONE
    assert not mon.watchdog_expired(20.0, driving=False)  # open armature: nothing to guard


def test_stall_timer_restarts_when_the_shaft_turns():
    safety = SafetyConfig(
        current_max_a=10, speed_max_rad_s=300, stall_current_a=5, stall_time_s=0.1
    )
    m = SafetyMonitor(safety)
    for k in range(90):
        assert m.check(k * DT, 6.0, 0.0) is None
    assert m.check(0.09, 6.0, 5.0) is None  # turned: timer restarts
    for k in range(91, 190):
        assert m.check(k * DT, 6.0, 0.0) is None
    assert m.check(0.3, 6.0, 0.0) is AbortReason.STALL


def test_negative_or_nan_safety_limits_are_refused():
    with pytest.raises(ParameterError, match="watchdog_s must be a number >= 0"):
        SafetyConfig(current_max_a=1.0, speed_max_rad_s=1.0, watchdog_s=-1.0)
    with pytest.raises(ParameterError, match="current_max_a"):
        SafetyConfig(current_max_a=math.nan, speed_max_rad_s=1.0)
