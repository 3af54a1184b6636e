"""Simulated motor backend: the core model on an exact sample grid, read through sensors.

:class:`SimBackend` implements :class:`~pmdc_ident.backends.base.Backend` over
:class:`~pmdc_ident.core.model.Plant`. Sample ``k`` is the plant state at time
``k * dt_s`` after :meth:`SimBackend.start`; which samples exist is decided
from a monotonic clock (injectable for tests), never from how often the host
polls, so timer jitter changes neither the physics nor the stamps.

Timing of commands: a command arriving between grid instants takes effect at
the next one (the backend first produces every sample already due under the
old command), exactly like a digital driver whose PWM updates on its own tick.

Host stalls: if more than ``max_catch_up_s`` of samples are due at once (the
host was suspended or badly overloaded), the plant is still advanced over the
gap, so the physics stays continuous and the stamps stay aligned with the
clock, but those samples are not returned. The first returned sample after
the gap carries :attr:`Fault.LINK`, and :attr:`SimBackend.skipped_samples`
counts what was left out. A gap longer than ``max_silent_s`` freezes the
simulated motor instead (its clock origin moves), which bounds the work.

Trips: a sample whose true current or speed exceeds ``limits.current_max_a`` /
``limits.speed_max_rad_s`` puts the motor in its safe state from that sample on
(as board firmware would, independent of host timing) and flags
:attr:`Fault.OVER_CURRENT` / :attr:`Fault.OVER_SPEED` until the next valid
command; latching and refusing commands is the driver node's job.

Sensors follow :func:`pmdc_ident.core.excitation.apply_sensors`: Gaussian noise
from a seeded generator on current and speed (speed reading = true speed +
noise), encoder angle quantised down to whole counts.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from pmdc_ident.backends.base import BackendError, Telemetry
from pmdc_ident.core.enums import Fault, SafeMode
from pmdc_ident.core.excitation import apply_sensors
from pmdc_ident.core.model import Plant
from pmdc_ident.core.motors import Limits, MotorSpec, SensorSpec

__all__ = ["SimBackend"]


class SimBackend:
    """A simulated PMDC motor behind the :class:`Backend` interface.

    Args:
        spec: the motor (model, sensors and limits) from :func:`load_motor`.
        dt_s: sample period of the grid.
        sensors: overrides ``spec.sensors`` (noise, encoder resolution).
        limits: overrides ``spec.limits`` (e.g. a reduced voltage limit).
        safe_mode: what :meth:`make_safe` does: open the armature or hold 0 V.
        seed: seed of the measurement-noise generator.
        clock: monotonic time source in seconds (``time.monotonic`` by default).
        max_catch_up_s: largest backlog returned by one :meth:`poll`.
        max_silent_s: largest gap the plant is advanced over without output.
        substeps: plant sub-steps per sample.
    """

    def __init__(
        self,
        spec: MotorSpec,
        dt_s: float,
        *,
        sensors: SensorSpec | None = None,
        limits: Limits | None = None,
        safe_mode: SafeMode = SafeMode.OPEN,
        seed: int | None = 0,
        clock: Callable[[], float] = time.monotonic,
        max_catch_up_s: float = 0.5,
        max_silent_s: float = 10.0,
        substeps: int = 8,
    ) -> None:
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            msg = f"sample period dt_s must be a positive number of seconds, got {dt_s}"
            raise BackendError(msg)
        self.spec = spec
        self._plant = Plant(spec.model, dt_s, substeps)
        self._dt_s = float(dt_s)
        self._sensors = sensors if sensors is not None else spec.sensors
        self._limits = limits if limits is not None else spec.limits
        self._safe_mode = SafeMode(safe_mode)
        self._rng = np.random.default_rng(seed)
        self._clock = clock
        self._max_catch_up = max(1, int(max_catch_up_s / self._dt_s))
        self._max_silent = max(self._max_catch_up, int(max_silent_s / self._dt_s))
        self._t0: float | None = None
        self._command_v = math.nan  # NaN = armature open
        self._flags = Fault.NONE  # sticky until the next valid command
        self._gap_flag = Fault.NONE  # set on the first sample after a stall
        self._pending: list[Telemetry] = []
        self._next_index = 0  # index of the next sample to produce
        self.skipped_samples = 0
        self.stalls = 0

    # -- Backend protocol -----------------------------------------------------------
    @property
    def dt_s(self) -> float:
        return self._dt_s

    @property
    def limits(self) -> Limits:
        return self._limits

    @property
    def safe_mode(self) -> SafeMode:
        return self._safe_mode

    @property
    def started(self) -> bool:
        return self._t0 is not None

    @property
    def armature_open(self) -> bool:
        return math.isnan(self._command_v)

    @property
    def command_v(self) -> float:
        """The command being applied (NaN while the armature is open)."""
        return self._command_v

    @property
    def plant(self) -> Plant:
        """The simulated motor (true, noise-free state)."""
        return self._plant

    def start(self) -> None:
        if self._t0 is None:
            self._command_v = math.nan
            self._t0 = self._clock()

    def command_voltage(self, voltage_v: float) -> float:
        try:
            v = float(voltage_v)
        except (TypeError, ValueError):
            msg = f"voltage command must be a number, got {voltage_v!r}"
            raise BackendError(msg) from None
        if not math.isfinite(v):
            self._advance()
            self._flags |= Fault.BAD_COMMAND
            msg = f"voltage command {v} refused (not finite); motor kept safe"
            raise BackendError(msg)
        if self._t0 is None:
            msg = "simulated backend not started; call start() first"
            raise BackendError(msg)
        self._advance()
        vmax = self._limits.voltage_max_v
        self._flags = Fault.NONE
        if abs(v) > vmax:
            v = math.copysign(vmax, v)
            self._flags |= Fault.CLAMPED
        self._command_v = v
        return v

    def open_armature(self) -> None:
        self._advance()
        self._command_v = math.nan

    def make_safe(self) -> None:
        try:
            self._advance()
        except Exception:  # noqa: BLE001 - make_safe never raises
            pass
        self._command_v = math.nan if self._safe_mode is SafeMode.OPEN else 0.0

    def poll(self) -> list[Telemetry]:
        self._advance()
        out, self._pending = self._pending, []
        return out

    def close(self) -> None:
        self.make_safe()
        self._t0 = None

    def _is_safe(self) -> bool:
        v = self._command_v
        return math.isnan(v) if self._safe_mode is SafeMode.OPEN else v == 0.0

    # -- the grid -----------------------------------------------------------------------
    def _due(self) -> int:
        """Number of samples whose time k*dt has been reached and not yet produced."""
        if self._t0 is None:
            return 0
        elapsed = self._clock() - self._t0
        # sample k exists once k*dt <= elapsed (1 ns slack for float rounding)
        last = math.floor(elapsed / self._dt_s + 1e-9)
        return max(0, last + 1 - self._next_index)

    def _advance(self) -> None:
        n = self._due()
        if n == 0:
            return
        backlog = len(self._pending) + n
        if backlog > self._max_catch_up:
            self._skip(backlog - self._max_catch_up)
            n = self._due()
            if n == 0:
                return
        self._produce(n)

    def _skip(self, n_skip: int) -> None:
        """A host stall: leave ``n_skip`` of the due samples out of the output."""
        self.stalls += 1
        self._gap_flag = Fault.LINK
        from_pending = min(n_skip, len(self._pending))
        if from_pending:  # drop the oldest undelivered samples first
            self._pending = self._pending[from_pending:]
        n_new = n_skip - from_pending
        if n_new > self._max_silent:
            # Very long gap: freeze the simulated motor over the excess.
            excess = n_new - self._max_silent
            assert self._t0 is not None
            self._t0 += excess * self._dt_s
            n_new = self._max_silent
        v = None if math.isnan(self._command_v) else self._command_v
        for _ in range(n_new):
            self._plant.step(v)
        self._next_index += n_new
        self.skipped_samples += n_skip

    def _produce(self, n: int) -> None:
        plant = self._plant
        ilim, wlim = self._limits.current_max_a, self._limits.speed_max_rad_s
        cur = np.empty(n)
        spd = np.empty(n)
        pos = np.empty(n)
        volts = np.empty(n)
        flags = [self._flags] * n
        for j in range(n):
            i, w = plant.current_a, plant.speed_rad_s
            cur[j], spd[j], pos[j] = i, w, plant.position_rad
            trip = Fault.OVER_CURRENT if abs(i) > ilim else Fault.NONE
            if abs(w) > wlim:
                trip |= Fault.OVER_SPEED
            if trip and not self._is_safe():
                # like board firmware: safe from this very sample, whatever the host does
                self._command_v = math.nan if self._safe_mode is SafeMode.OPEN else 0.0
                self._flags |= trip
            flags[j] = self._flags
            volts[j] = v = self._command_v
            plant.step(None if math.isnan(v) else v)
        i_m, w_m, th_m = apply_sensors(cur, spd, pos, self._sensors, self._rng)
        first = self._next_index
        dt = self._dt_s
        batch = [
            Telemetry(
                sample_index=first + j,
                time_s=(first + j) * dt,
                current_a=float(i_m[j]),
                position_rad=float(th_m[j]),
                speed_rad_s=float(w_m[j]),
                voltage_cmd_v=float(volts[j]),
                faults=flags[j],
            )
            for j in range(n)
        ]
        if self._gap_flag:
            batch[0] = replace(batch[0], faults=batch[0].faults | self._gap_flag)
            self._gap_flag = Fault.NONE
        self._pending.extend(batch)
        self._next_index += n
