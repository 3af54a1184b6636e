"""Telemetry frames to samples, on the board's own clock.

Sample ``k`` of a stream is stamped ``(base + counter) * dt_s``, the board's sample
counter, never the host's arrival time. Gaps in the counter are counted as dropped
samples and flag :attr:`Fault.LINK` on the next sample. Speed is the backward
difference of the encoder count over the counter interval (0 on the first sample of a
session's stream, where the rotor starts at rest; a stream that resumes after a link
loss or a board reset publishes from its second sample: the rotor may be coasting).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from pmdc_ident.backends.base import Telemetry
from pmdc_ident.backends.serial_link.errors import LinkLostError
from pmdc_ident.core.enums import Fault
from pmdc_ident.protocol import HelloAck
from pmdc_ident.protocol import Telemetry as WireTelemetry
from pmdc_ident.protocol.messages import NOT_MEASURED

__all__ = ["SampleDecoder"]

_STICKY_REPORTED = Fault.OVER_CURRENT | Fault.OVER_SPEED | Fault.WATCHDOG | Fault.BAD_COMMAND


class SampleDecoder:
    """One board's telemetry, stream after stream, as one time axis of samples."""

    def __init__(self, dt_s: float, port_name: str, log: Callable[[str], None]) -> None:
        self.info: HelloAck | None = None  # the board's HELLO_ACK of the current stream
        self.samples_total = 0
        self.dropped = 0
        self._dt_s = dt_s
        self._port = port_name
        self._log = log
        self._next_index = 0
        self._base = 0
        self._last_counter: int | None = None
        self._counter_acc = 0
        self._last_count = 0
        self._pos_counts = 0
        self._pos_offset_rad = 0.0
        self._last_position = 0.0
        self._resumed = False  # the stream resumes after a link loss: the rotor may turn
        self._link_flag = False
        self._last_faults = Fault.NONE

    def begin(self, info: HelloAck, now: float, lost_at: float) -> None:
        """A stream starts (``now``); the link was lost at ``lost_at`` (0: never)."""
        self.info = info
        if self.samples_total and lost_at:
            # Continue the time axis across the outage, on the board's grid.
            gap = int(round((now - lost_at) / self._dt_s))
            self._next_index += max(0, gap)
        self._base = self._next_index
        self._last_counter = None
        self._counter_acc = 0
        self._pos_offset_rad = self._last_position
        self._pos_counts = 0
        self._resumed = self.samples_total > 0
        self._last_faults = Fault.NONE

    def flag_link(self) -> None:
        """The next sample carries :attr:`Fault.LINK` (a link error was seen)."""
        self._link_flag = True

    def decode(self, t: WireTelemetry) -> Telemetry | None:
        """The sample of one telemetry frame (``None`` while a resumed stream's count
        starts); raises LinkLostError when the board's counter goes back."""
        info = self.info
        assert info is not None
        step = self._step(t.counter)
        if step == 0:
            self._last_count = t.encoder_count
            return None
        delta = 0 if self._last_counter is None else _wrapped(t.encoder_count - self._last_count)
        if step > 1 and self._last_counter is not None:
            self.dropped += step - 1
            self._link_flag = True
        self._counter_acc += step if self._last_counter is not None else 0
        self._last_counter = t.counter
        self._last_count = t.encoder_count
        self._pos_counts += delta
        rad_per_count = 2.0 * math.pi / info.counts_per_rev
        index = self._base + self._counter_acc
        position = self._pos_offset_rad + self._pos_counts * rad_per_count
        speed = delta * rad_per_count / (step * self._dt_s)
        faults = self._faults(t.faults)
        current_a, applied_v, terminal_v, supply_v = _readings(info, t)
        sample = Telemetry(
            sample_index=index,
            time_s=index * self._dt_s,
            current_a=current_a,
            position_rad=position,
            speed_rad_s=speed,
            voltage_cmd_v=applied_v,
            terminal_voltage_v=terminal_v,
            supply_voltage_v=supply_v,
            faults=faults,
        )
        self.samples_total += 1
        self._next_index = index + 1
        self._last_position = position
        return sample

    def _step(self, counter: int) -> int:
        """Board periods since the last frame (1 on a stream's first); 0: count only."""
        if self._last_counter is None:
            if self._resumed:
                # A stream resumed after a link loss or a board reset: the rotor may still
                # turn (it coasts while the board reboots), and one count gives no speed.
                # Publishing 0 would be a false reading (a 265 rad/s coast read 0 for one
                # sample): this sample only starts the count, the next is the first out.
                self._resumed = False
                self._last_counter = counter
                return 0
            return 1
        step = (counter - self._last_counter) & 0xFFFFFFFF
        if step == 0 or step >= 0x80000000:
            msg = (
                f"board sample counter went back ({self._last_counter} -> {counter}): board reset?"
            )
            raise LinkLostError(msg)
        return step

    def _faults(self, bits: int) -> Fault:
        faults = Fault(bits & 0x7F)
        if self._link_flag:
            faults |= Fault.LINK
            self._link_flag = False
        new = (faults & ~self._last_faults) & _STICKY_REPORTED
        if new:
            names = "|".join(f.name or "?" for f in Fault if f and f in new)
            self._log(f"serial board {self._port}: board reports {names} (armature opened)")
        self._last_faults = faults
        return faults


def _readings(info: HelloAck, t: WireTelemetry) -> tuple[float, float, float, float]:
    """Current (A), applied, terminal and supply voltage (V); NaN where not measured."""
    # The LSBs travel as float32: 7 significant digits are all they carry.
    lsb_v = float(f"{info.voltage_lsb_v:.7g}")
    lsb_a = float(f"{info.current_lsb_a:.7g}")
    return (
        math.nan if t.current == NOT_MEASURED else t.current * lsb_a,
        math.nan if t.applied_v == NOT_MEASURED else t.applied_v * lsb_v,
        math.nan if t.terminal_v == NOT_MEASURED else t.terminal_v * lsb_v,
        math.nan if t.supply_v == NOT_MEASURED else t.supply_v * lsb_v,
    )


def _wrapped(delta: int) -> int:
    """A 32-bit encoder difference as a signed count."""
    return ((delta + 2**31) % 2**32) - 2**31
