"""The driver's decisions without ROS: limits capped at the motor file's, a watchdog
that cannot be switched off at run time, an ordered stop, an idle watchdog that is no
fault (issue 24)."""

from __future__ import annotations

import math
from typing import Any

import pytest

from pmdc_ident.backends.factory import BackendConfigError
from pmdc_ident.backends.status import Level
from pmdc_ident.core.enums import LogLevel
from pmdc_ident.core.motors import load_motor
from pmdc_ident.node_logic.driver import Driver
from pmdc_ident.process.parameter_tables import DRIVER

SPEC = load_motor("seed000_ebike")  # 24 V, 30 A, 450 rad/s


class Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def _driver(**cfg: Any) -> tuple[Driver, Clock, list[tuple[LogLevel, str]]]:
    clock, logs = Clock(), []

    def log(level: LogLevel, text: str) -> None:
        assert isinstance(level, LogLevel), (level, text)  # the node's logger needs one
        logs.append((level, text))

    d = Driver({**DRIVER.defaults(), **cfg}, log, clock)
    return d, clock, logs


@pytest.mark.parametrize(
    ("name", "value", "fragment", "ok"),
    [
        ("current_limit_a", 500.0, "current_limit_a 500 A is above the limit of motor "
         "seed000_ebike (30 A", 20.0),
        ("speed_limit_rad_s", 99999.0, "speed_limit_rad_s 99999 rad/s is above the limit of "
         "motor seed000_ebike (450 rad/s", 300.0),
        ("voltage_limit_v", 48.0, "voltage_limit_v 48 V is above the limit of motor "
         "seed000_ebike (24 V", 12.0),
        ("watchdog_s", 0.0, "would switch the watchdog off", 3.0),
    ],
)  # fmt: skip
def test_no_runtime_change_raises_a_limit_past_the_motor_file_or_stops_the_watchdog(
    name, value, fragment, ok
):
    d, _, _ = _driver()
    try:
        assert fragment in d.check_value(name, value)
        assert d.check_value(name, ok) == ""  # within the motor's limits: accepted
        assert d.check_value(name, 0.0, runtime=False) == ""  # 0 at start: the motor's / off
    finally:
        d.shutdown_safe()


@pytest.mark.parametrize(
    ("name", "value"), [("current_limit_a", 31.0), ("speed_limit_rad_s", 451.0)]
)
def test_a_start_value_above_the_motor_file_is_refused(name, value):
    with pytest.raises(BackendConfigError, match=f"{name} .* is above the limit of motor"):
        _driver(**{name: value})


def test_a_stop_holds_zero_volts_until_the_commanding_node_has_gone():
    d, clock, logs = _driver(stop_wait_s=3.0)
    try:
        d.command(9.75)
        assert d.backend.command_v == 9.75
        line = d.begin_stop(clock(), commanders=1)
        assert line.startswith("stopping: 0 V applied") and d.backend.command_v == 0.0
        d.command(9.75)  # the plan's next command, sent before that node saw the signal
        assert d.backend.command_v == 0.0
        assert any("refused: the driver is stopping" in t for _, t in logs)
        d.command(0.0)  # the identification node's own safe command: taken
        assert d.backend.command_v == 0.0 and not d.stop_complete(clock(), commanders=1)
        assert d.stop_complete(clock(), commanders=0)  # it has gone
        clock.t = 3.0
        assert d.stop_complete(clock(), commanders=1)  # or stop_wait_s is over
        assert "armature open" in d.shutdown_safe()  # then the safe mode (open)
        assert math.isnan(d.backend.command_v)
    finally:
        d.shutdown_safe()


def test_a_stop_with_no_commanding_node_goes_straight_to_the_safe_mode():
    d, clock, _ = _driver()
    try:
        d.command(5.0)
        assert d.begin_stop(clock(), commanders=0).startswith("stopping: 5 V applied, no node")
        assert d.stop_complete(clock(), commanders=0)
    finally:
        d.shutdown_safe()


def test_the_watchdog_after_a_session_ended_at_zero_volts_is_no_fault():
    """A session ends with 0 V and stops commanding: the watchdog opens the armature and
    the driver's status stays OK (it stayed at WARN 'watchdog: tripped' until the next
    command); commands that stop at a voltage still warn."""
    d, clock, logs = _driver(watchdog_s=0.5)
    try:
        d.command(0.0)
        clock.t = 0.6
        d.poll()
        assert math.isnan(d.backend.command_v)  # opened
        status = d.status(d.rate_hz, 10)
        assert status.level is Level.OK and status.values["watchdog"] == "ok", status
        assert (LogLevel.INFO, "no voltage_cmd for 0.5 s at 0 V: armature opened") in logs
        d.command(6.0)
        clock.t = 1.2
        d.poll()
        status = d.status(d.rate_hz, 10)
        assert status.level is Level.WARN and status.values["watchdog"] == "tripped"
        assert any("raise watchdog_s" in t for lvl, t in logs if lvl == LogLevel.WARNING)
    finally:
        d.shutdown_safe()


class _Lossy:
    """The driver's backend, with samples it did not publish: skipped after a host stall
    (any backend) and lost on a board's link (a serial backend's counter gaps)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.skipped_samples = 0
        self.dropped = 0

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    @property
    def link_stats(self) -> Any:
        from types import SimpleNamespace

        return SimpleNamespace(dropped_samples=self.dropped)


def test_samples_the_backend_did_not_publish_are_said_at_once_then_once_a_second():
    d, clock, logs = _driver()
    lossy = _Lossy(d.backend)
    d.backend = lossy
    said = lambda: [t for lvl, t in logs if "not published" in t]  # noqa: E731
    try:
        d.poll()
        assert said() == []
        lossy.skipped_samples = 300
        d.poll()
        assert said() == [
            "driver samples not published: 300 skipped after a host stall (the driver polled "
            "too late to publish them; 300 so far); their stamps stay holes on the sample grid"
        ]
        assert logs[-1][0] == LogLevel.WARNING
        lossy.dropped, lossy.skipped_samples = 5, 350
        d.poll()  # within the second: held back, not lost
        assert len(said()) == 1
        clock.t = 1.0
        d.poll()
        assert said()[-1] == (
            "driver samples not published: 50 skipped after a host stall (the driver polled "
            "too late to publish them; 350 so far); 5 lost on the link (gaps in the board's "
            "sample counter; 5 so far); their stamps stay holes on the sample grid"
        )
        clock.t = 5.0
        d.poll()
        assert len(said()) == 2  # nothing new
        lossy.skipped_samples = 360
        d.poll()
        lossy.skipped_samples = 370  # within the second, then the driver stops: said then
    finally:
        d.shutdown_safe()
    assert len(said()) == 4 and said()[-1].startswith(
        "driver samples not published: 10 skipped after a host stall"
    )
