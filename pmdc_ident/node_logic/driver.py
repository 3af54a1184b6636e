"""The motor driver's decisions, ROS-free: what the driver node does with a command,
a sample, a service call or a parameter change.

:class:`Driver` owns the backend and the one :class:`SafetyMonitor`: a non-finite
command makes the motor safe; a latched trip refuses commands until
:meth:`Driver.reset_faults`; commands above the voltage limit are clamped; every
sample is checked (and a trip the backend itself reports latches too, so a trip in
samples a host stall skipped is not missed); the watchdog opens a driven armature
that gets no command. The node turns its callbacks into these calls and publishes
what :meth:`Driver.poll` returns. Logs go through ``log(level, text)``; a repeated
warning about commands (refused, clamped, not finite) is written at most once a
second per kind.

Limits never rise above the motor file's: ``voltage_limit_v``, ``current_limit_a``
and ``speed_limit_rad_s`` above it are refused at start and at run time
(:meth:`Driver.check_value`, the node's one set-parameters callback), and the
watchdog cannot be switched off while the driver runs.

Stopping (Ctrl-C, SIGTERM, ``ros2 launch`` ending) is ordered so that the motor sees
0 V before the armature opens, whichever process gets the signal first:
:meth:`Driver.begin_stop` applies 0 V to a closed armature and from then on takes only
0 V or an opening; the node keeps publishing samples until no node commands it any
more (the identification node has confirmed its safe state and left) or
``stop_wait_s`` has passed (:meth:`Driver.stop_complete`); then
:meth:`Driver.shutdown_safe` applies the safe mode (``open`` by default).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from pmdc_ident.backends.base import Backend, BackendError, Telemetry
from pmdc_ident.backends.factory import BackendConfigError, make_backend
from pmdc_ident.backends.status import DriverStatus, armature_text, fault_names
from pmdc_ident.core.enums import Fault, LogLevel, SafeMode
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.motors import Limits, MotorSpec, load_motor
from pmdc_ident.core.safety import SafetyConfig, SafetyMonitor

__all__ = ["Driver", "Log"]

Log = Callable[[LogLevel, str], None]  # (level, text)
THROTTLE_S = 1.0
_TRIP_BITS = Fault.OVER_CURRENT | Fault.OVER_SPEED
# limit parameters capped at the motor file's: name -> (cap, unit) of the motor's limits
_CAPPED: dict[str, Callable[[Limits], tuple[float, str]]] = {
    "voltage_limit_v": lambda lim: (lim.voltage_max_v, "V"),
    "current_limit_a": lambda lim: (lim.current_max_a, "A"),
    "speed_limit_rad_s": lambda lim: (lim.speed_max_rad_s, "rad/s"),
}


class Driver:
    """One motor driver: backend, limits, trips and watchdog (see the module docs)."""

    def __init__(self, cfg: Mapping[str, Any], log: Log, clock_s: Callable[[], float]) -> None:
        self.log = log
        self.clock_s = clock_s
        try:
            self.spec: MotorSpec = load_motor(cfg["motor"])
        except PmdcError as exc:
            raise BackendConfigError(f"parameter motor: {exc}") from None
        for name in _CAPPED:
            reason = self.check_value(name, cfg[name], runtime=False)
            if reason:
                raise BackendConfigError(reason)
        self.name = str(cfg["backend"])
        self.rate_hz = float(cfg["rate_hz"])
        self.safe_mode = SafeMode(cfg["safe_mode"])
        self.voltage_limit_v = self._voltage_limit(cfg["voltage_limit_v"])
        limits = self.spec.limits
        self.safety = SafetyMonitor(
            SafetyConfig(
                current_max_a=cfg["current_limit_a"] or limits.current_max_a,
                speed_max_rad_s=cfg["speed_limit_rad_s"] or limits.speed_max_rad_s,
                data_timeout_s=0.0,  # the driver publishes; the session watches the data
                watchdog_s=cfg["watchdog_s"],
                non_finite_trips=False,  # a sensor may report 'not measured'
            )
        )
        self.stop_wait_s = float(cfg.get("stop_wait_s", 0.0))
        self.stopping = False  # begin_stop: only 0 V or an opening from now on
        self._stop_deadline_s = math.inf
        self.driving = False  # a user command is being applied (the watchdog guards it)
        self.clamped = False
        self.link_error = ""
        self.last_sample_v = math.nan  # command of the last sample polled
        self._unpublished_said = (0, 0)  # (skipped, dropped) samples said so far
        self._reported = Fault.NONE  # trip bits in the backend's previous sample
        self._said: dict[str, float] = {}  # throttled message kind -> when last written
        # The backend trips at the monitor's limits itself (per sample, like board
        # firmware); the monitor latches the trip and applies runtime changes.
        backend_limits = Limits(
            voltage_max_v=limits.voltage_max_v,
            current_max_a=self.safety.config.current_max_a,
            speed_max_rad_s=self.safety.config.speed_max_rad_s,
        )
        self.backend: Backend = make_backend(
            cfg, self.spec, backend_limits, lambda text: log(LogLevel.WARNING, text)
        )
        try:
            self.backend.start()
        except BaseException as exc:
            try:
                self.backend.close()  # leave a half-opened port released, the motor safe
            except Exception:  # noqa: BLE001 - the start error is the one to report
                pass
            if isinstance(exc, PmdcError | OSError):
                msg = f"cannot start the {self.name} backend: {exc}"
                raise BackendConfigError(msg) from None
            raise

    def started_line(self) -> str:
        return (
            f"driver started: backend {self.name}, motor {self.spec.name}, "
            f"{self.rate_hz:g} Hz, voltage limit {self.voltage_limit_v:g} V, "
            f"safe mode {self.safe_mode.value}, armature open"
        )

    # -- parameters ----------------------------------------------------------------------
    def check_value(self, name: str, value: Any, *, runtime: bool = True) -> str:
        """Why a value is refused beyond the table's range ('' if it is fine): no limit
        above the motor file's, and (at run time) no watchdog switched off."""
        if name in _CAPPED:
            cap, unit = _CAPPED[name](self.spec.limits)
            if value > cap:
                return (
                    f"parameter {name} {value:g} {unit} is above the limit of motor "
                    f"{self.spec.name} ({cap:g} {unit}); 0 = the motor's limit"
                )
        if name == "watchdog_s" and runtime and not value > 0:
            return (
                "parameter watchdog_s 0 would switch the watchdog off while the driver runs: "
                "refused (give a timeout in seconds, e.g. 1.5 on a busy machine)"
            )
        return ""

    def _voltage_limit(self, value: float) -> float:
        return float(value) if value > 0.0 else self.spec.limits.voltage_max_v

    def apply_parameter(self, name: str, value: Any) -> None:
        """A runtime change the node accepted (0 = the motor's limit)."""
        limits = self.spec.limits
        if name == "voltage_limit_v":
            self.voltage_limit_v = self._voltage_limit(value)
        elif name == "current_limit_a":
            self.safety.update(current_max_a=value or limits.current_max_a)
        elif name == "speed_limit_rad_s":
            self.safety.update(speed_max_rad_s=value or limits.speed_max_rad_s)
        elif name == "watchdog_s":
            self.safety.update(watchdog_s=value)
        self.log(LogLevel.INFO, f"parameter {name} set to {value!r}")

    def _say(self, kind: str, level: LogLevel, text: str) -> None:
        """``text`` at most once every THROTTLE_S per ``kind`` (commands come at 1 kHz)."""
        now = self.clock_s()
        if now - self._said.get(kind, -math.inf) >= THROTTLE_S:
            self._said[kind] = now
            self.log(level, text)

    # -- commands ------------------------------------------------------------------------
    def command(self, voltage_v: float) -> None:
        v = float(voltage_v)
        if not math.isfinite(v):
            self.make_safe()
            self._say(
                "nonfinite",
                LogLevel.WARNING,
                f"voltage_cmd {v} refused (not finite): motor made safe",
            )
            return
        if self.safety.tripped:
            text = f"voltage_cmd refused: {self.safety.message()}; call reset_faults"
            self._say("refused", LogLevel.WARNING, text)
            return
        if self.stopping and v != 0.0:
            text = f"voltage_cmd {v:g} V refused: the driver is stopping (0 V, then open)"
            self._say("stopping", LogLevel.WARNING, text)
            return
        limit = self.voltage_limit_v
        self.clamped = abs(v) > limit
        if self.clamped:
            self._say("clamped", LogLevel.WARNING, f"voltage_cmd {v:g} V clamped to +-{limit:g} V")
            v = math.copysign(limit, v)
        try:
            self.backend.command_voltage(v)
        except BackendError as exc:
            self.make_safe()
            self._say("command", LogLevel.ERROR, f"{exc}; motor made safe")
            return
        self.driving = True
        self.safety.command_received(self.clock_s())

    def open_armature(self) -> tuple[bool, str]:
        try:
            self.backend.open_armature()
        except BackendError as exc:
            self.make_safe()
            self.log(LogLevel.ERROR, f"{exc}; motor made safe")
            return False, f"{exc}; motor made safe"
        self.driving = False
        text = "armature open (coasting); the next voltage_cmd closes it"
        self.log(LogLevel.INFO, text)
        return True, text

    def reset_faults(self) -> tuple[bool, str]:
        was = self.safety.message() or "no latched fault"
        self.safety.reset()
        self.log(LogLevel.INFO, f"cleared: {was}")
        return True, f"cleared: {was}"

    def make_safe(self) -> None:
        self.driving = False
        self.backend.make_safe()

    # -- stopping ------------------------------------------------------------------------
    @property
    def armature_closed(self) -> bool:
        return not math.isnan(getattr(self.backend, "command_v", self.last_sample_v))

    def begin_stop(self, now_s: float, commanders: int) -> str:
        """A stop was requested while ``commanders`` nodes publish ``voltage_cmd``: 0 V on
        a closed armature at once, then only 0 V or an opening until
        :meth:`stop_complete`; the line to log."""
        self.stopping = True
        self._stop_deadline_s = now_s + self.stop_wait_s
        if commanders <= 0:
            return f"stopping: {self.state_text()}, no node commands this driver"
        wait = f"at most {self.stop_wait_s:g} s"
        if self.safety.tripped or not self.armature_closed:
            return f"stopping: {self.state_text()}; waiting for the nodes commanding it ({wait})"
        try:
            self.backend.command_voltage(0.0)
        except BackendError as exc:
            self.make_safe()
            return f"stopping: {exc}; motor made safe"
        return (
            f"stopping: 0 V applied; the armature opens once no node commands this driver ({wait})"
        )

    def stop_complete(self, now_s: float, commanders: int) -> bool:
        """The stop may finish: no node publishes ``voltage_cmd`` any more, or the wait
        is over (``commanders``: publishers of ``voltage_cmd``)."""
        return commanders <= 0 or now_s >= self._stop_deadline_s

    # -- samples -------------------------------------------------------------------------
    def poll(self) -> list[Telemetry] | None:
        """The backend's new samples, each checked; the watchdog after them. ``None``
        when the backend's link failed (the motor is then made safe)."""
        try:
            samples = self.backend.poll()
        except BackendError as exc:  # link lost (serial): safe, report, keep running
            self.make_safe()
            self.link_error = str(exc)
            self.log(LogLevel.ERROR, f"backend: {exc}")
            return None
        self._report_unpublished()
        for s in samples:
            self._check(s)
        if samples:
            self.last_sample_v = samples[-1].voltage_cmd_v
        if self.safety.watchdog_expired(self.clock_s(), self.driving):
            idle = getattr(self.backend, "command_v", self.last_sample_v) == 0.0
            self.backend.open_armature()
            self.driving = False
            timeout = self.safety.config.watchdog_s
            if idle:
                # 0 V was the last command (a session's end, a controller that parked the
                # motor): opening it is the normal way to idle, not a fault to report
                self.safety.watchdog_tripped = False
                self.log(
                    LogLevel.INFO, f"no voltage_cmd for {timeout:g} s at 0 V: armature opened"
                )
            else:
                self.log(
                    LogLevel.WARNING,
                    f"watchdog: no voltage_cmd for {timeout:g} s, armature opened (raise "
                    "watchdog_s if the commanding node is only slow on a busy machine)",
                )
        return samples

    def _check(self, s: Telemetry) -> None:
        trip = self.safety.check(s.time_s, s.current_a, s.speed_rad_s)
        reported = s.faults & _TRIP_BITS
        new = reported & ~self._reported
        self._reported = reported
        if trip is None and new:
            trip = self.safety.report(new, s.time_s)
        if trip is not None:
            self.make_safe()
            self.log(LogLevel.ERROR, f"{self.safety.latched[trip]}: motor made safe")

    def _report_unpublished(self, final: bool = False) -> None:
        """One warning line (at most once a second, with the totals) whenever samples
        were not published: skipped after a host stall, or lost on a board's link
        (gaps in its sample counter). Their stamps stay holes on the grid, which the
        recorder and the identification count; the driver says so first, here."""
        skipped = int(getattr(self.backend, "skipped_samples", 0))
        link = getattr(self.backend, "link_stats", None)  # serial backend only
        dropped = int(link.dropped_samples) if link is not None else 0
        if (skipped, dropped) == self._unpublished_said:
            return
        now = self.clock_s()
        if not final and now - self._said.get("unpublished", -math.inf) < THROTTLE_S:
            return  # said again once the second is over, with the new totals
        self._said["unpublished"] = now
        before_skipped, before_dropped = self._unpublished_said
        self._unpublished_said = (skipped, dropped)
        parts = []
        if skipped != before_skipped:
            why = (
                "the simulated motor kept running"
                if link is None
                else "the driver polled too late to publish them"
            )
            parts.append(
                f"{skipped - before_skipped} skipped after a host stall ({why}; {skipped} so far)"
            )
        if dropped != before_dropped:
            parts.append(
                f"{dropped - before_dropped} lost on the link (gaps in the board's sample "
                f"counter; {dropped} so far)"
            )
        self.log(
            LogLevel.WARNING,
            "driver samples not published: " + "; ".join(parts) + "; their stamps stay "
            "holes on the sample grid",
        )

    # -- state ---------------------------------------------------------------------------
    def faults(self) -> Fault:
        f = self.safety.faults
        return f | Fault.CLAMPED if self.clamped else f

    def state_text(self) -> str:
        """The armature state: the backend's current command where it exposes one
        (sim), else the command of the last sample (serial)."""
        return armature_text(getattr(self.backend, "command_v", self.last_sample_v))

    def status(self, delivered_hz: float, published: int) -> DriverStatus:
        faults = self.faults()
        link = getattr(self.backend, "link_stats", None)  # serial backend only
        values = {
            "backend": self.name,
            "motor": self.spec.name,
            "sample rate set (Hz)": f"{self.rate_hz:g}",
            "sample rate delivered (Hz)": f"{delivered_hz:.1f}",
            "samples published": str(published),
            "faults": fault_names(faults),
            "armature": self.state_text(),
            "voltage limit (V)": f"{self.voltage_limit_v:g}",
            "watchdog": "tripped" if self.safety.watchdog_tripped else "ok",
            "watchdog timeout (s)": f"{self.safety.config.watchdog_s:g}",
            "skipped samples (host stalls)": str(getattr(self.backend, "skipped_samples", 0)),
        }
        if link is not None:
            values.update({f"link {k}": v for k, v in link.as_strings().items()})
        return DriverStatus.of(
            faults=faults,
            trip_message=self.safety.message(),
            rate_set_hz=self.rate_hz,
            rate_delivered_hz=delivered_hz,
            link_error=self.link_error or (link.last_error if link is not None else ""),
            link_state=link.state.value if link is not None else None,
            values=values,
        )

    def shutdown_safe(self) -> str:
        """Make the motor safe and release the backend; returns the final state line."""
        try:
            self._report_unpublished(final=True)  # what the last second left unsaid
            self.backend.make_safe()
            if hasattr(self.backend, "command_v"):
                state = self.state_text()
            else:  # what make_safe commanded (no sample of it may arrive any more)
                state = armature_text(math.nan if self.safe_mode is SafeMode.OPEN else 0.0)
            self.backend.close()
        except Exception as exc:  # noqa: BLE001 - report, never raise on the way out
            return f"driver stopped: backend error while making safe ({exc})"
        return f"driver stopped: motor safe ({state}, safe mode {self.safe_mode.value})"
