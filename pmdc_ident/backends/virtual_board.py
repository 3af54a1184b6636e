"""A board in Python: the motor model behind the serial protocol on a pseudo-terminal.

:class:`VirtualBoard` opens a pty pair, keeps the master end and offers the
slave path as its ``port``; a host opens that path exactly as it would open
``/dev/ttyACM0``. Like a microcontroller it keeps its own sample clock: the
plant (:class:`pmdc_ident.core.model.Plant`) steps on an exact grid of the
negotiated period, scheduled from a monotonic clock as a timer ISR would be,
and each step is reported in one telemetry frame.

The kernel does not enforce a pty's baud rate, so the board paces its output
itself: a frame leaves the "wire" only after ``bytes * 10 / baud`` seconds
(8N1) behind the previous one, and received bytes are held for their wire
time before they are parsed. That makes the benchmark's rates and latencies
those of a real UART at that baud (plus the host's scheduling).

Fault injection for tests: :meth:`inject`, :meth:`corrupt_next`,
:meth:`truncate_next`, :meth:`stall`, :meth:`reset`, :meth:`unplug`.
"""

from __future__ import annotations

import collections
import math
import os
import select
import threading
import time
import tty

import numpy as np

from pmdc_ident.core.enums import Fault
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.model import Plant
from pmdc_ident.core.motors import MotorSpec
from pmdc_ident.protocol.board import BoardCore
from pmdc_ident.protocol.codec import cobs_decode, cobs_encode
from pmdc_ident.protocol.messages import (
    BITS_PER_BYTE,
    PROTOCOL_VERSION,
    Capability,
    min_period_us,
)

__all__ = ["VIRTUAL_MIN_PERIOD_US", "VirtualBoard"]

# The Python timer loop cannot hold a finer grid reliably on a loaded host.
VIRTUAL_MIN_PERIOD_US = 250
_TX_QUEUE_FRAMES = 64  # like a UART ring buffer: older telemetry is dropped beyond it


def _nice_lsb(full_scale: float) -> float:
    """Smallest of 1, 2, 5 x 10^k that spans +-1.5 full scale in int16 counts."""
    need = 1.5 * full_scale / 32000.0
    k = math.floor(math.log10(need))
    for m in (1.0, 2.0, 5.0, 10.0):
        if m * 10.0**k >= need:
            return m * 10.0**k
    return 10.0 ** (k + 1)  # pragma: no cover


class VirtualBoard:
    """The motor model on a pty, speaking the pmdc protocol; run it with :meth:`start`."""

    def __init__(
        self,
        motor: MotorSpec,
        *,
        baud: int = 115200,
        supply_v: float | None = None,
        seed: int = 0,
        protocol_version: int = PROTOCOL_VERSION,
        pace: bool = True,
        max_lag_s: float = 0.2,
    ) -> None:
        if baud < 1200:
            msg = f"baud must be >= 1200, got {baud}"
            raise ParameterError(msg)
        self.motor = motor
        self.baud = int(baud)
        self.pace = pace
        self.max_lag_s = float(max_lag_s)  # behind the grid by more: skip frames
        lim = motor.limits
        self.supply_v = float(supply_v if supply_v is not None else lim.voltage_max_v)
        cpr = int(motor.sensors.encoder_counts_per_rev) or 65536
        caps = (
            Capability.TERMINAL_VOLTAGE
            | Capability.SUPPLY_VOLTAGE
            | Capability.OPEN_ARMATURE
            | Capability.CURRENT
        )
        self.core = BoardCore(
            min_period_us=max(VIRTUAL_MIN_PERIOD_US, min_period_us(self.baud)),
            counts_per_rev=cpr,
            current_lsb_a=_nice_lsb(lim.current_max_a),
            voltage_lsb_v=_nice_lsb(max(lim.voltage_max_v, self.supply_v)),
            supply_nominal_v=self.supply_v,
            voltage_max_v=lim.voltage_max_v,
            capabilities=int(caps),
            protocol_version=protocol_version,
        )
        self._rng = np.random.default_rng(seed)
        self._plant: Plant | None = None
        # Compile/load the jitted kernel now, not inside the first timer tick.
        Plant(motor.model, 1e-3).step(0.0)
        self._byte_s = BITS_PER_BYTE / self.baud
        self._master, slave = os.openpty()
        tty.setraw(self._master)
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        # Keep the slave open ourselves so the pty survives host reconnects.
        self._slave = slave
        os.set_blocking(self._master, False)
        self._lock = threading.Lock()
        self._thread: threading.Thread | None = None
        self._running = False
        self._stalled = False
        self._corrupt = 0
        self._truncate = 0
        self._inject = bytearray()
        self._pending_reset = False
        self.frames_sent = 0
        self.telemetry_dropped = 0
        self.bytes_lost = 0
        self.samples_skipped = 0  # grid instants without a frame (process starved)
        self._tx: collections.deque[tuple[float, bytes, bool]] = collections.deque()
        self._tx_busy = 0.0
        self._rx: collections.deque[tuple[float, bytes]] = collections.deque()
        self._rx_busy = 0.0
        self._epoch = time.monotonic()
        self._next_tick = math.inf
        self._stream_start = 0.0

    # -- lifecycle -------------------------------------------------------------------
    def start(self) -> VirtualBoard:
        """Run the board in a background thread (returns self)."""
        self._running = True
        self._queue(self.core.boot(), time.monotonic(), telemetry=False)
        self._thread = threading.Thread(target=self._loop, name="virtual-board", daemon=True)
        self._thread.start()
        return self

    def run_forever(self) -> None:
        """Run in the calling thread until :meth:`stop` or KeyboardInterrupt."""
        self._running = True
        self._queue(self.core.boot(), time.monotonic(), telemetry=False)
        self._loop()

    def stop(self) -> None:
        self._running = False
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None

    def close(self) -> None:
        """Stop and release both ends of the pty."""
        self.stop()
        for fd in (self._master, self._slave):
            if fd >= 0:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._master = self._slave = -1

    def __enter__(self) -> VirtualBoard:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- fault injection --------------------------------------------------------------
    def unplug(self) -> None:
        """Cable pulled: the pty disappears; the host's next read fails."""
        self.close()

    def inject(self, data: bytes) -> None:
        """Put raw bytes on the board -> host line (garbage, partial frames)."""
        with self._lock:
            self._inject += data

    def corrupt_next(self, n: int = 1) -> None:
        """Flip one byte inside each of the next ``n`` frames (CRC errors on the host)."""
        with self._lock:
            self._corrupt += n

    def truncate_next(self, n: int = 1) -> None:
        """Cut the next ``n`` frames short before their delimiter."""
        with self._lock:
            self._truncate += n

    def stall(self, stalled: bool = True) -> None:
        """A hung board: no telemetry, no replies (the plant still runs)."""
        self._stalled = stalled

    def reset(self) -> None:
        """The MCU resets: BOOT frame, stream off, armature open, handshake needed."""
        with self._lock:
            self._pending_reset = True

    # -- inspection ---------------------------------------------------------------------
    @property
    def armature_open(self) -> bool:
        return self.core.setpoint_mv is None

    @property
    def speed_rad_s(self) -> float:
        return self._plant.speed_rad_s if self._plant is not None else 0.0

    # -- the loop ------------------------------------------------------------------------
    def _now_us(self, t: float) -> int:
        return int((t - self._epoch) * 1e6) & 0xFFFFFFFF

    def _queue(self, frame: bytes, t: float, telemetry: bool) -> None:
        if not frame:
            return
        # The ring overflows when frames come faster than the wire carries them. Frames
        # this thread makes late because its process was starved (within max_lag_s) are
        # ones a real MCU sent on time: they are not dropped for the host's stall.
        late = time.monotonic() - t > 2e-6 * self.core.period_us
        if len(self._tx) >= _TX_QUEUE_FRAMES and not late:
            self.telemetry_dropped += 1
            return
        self._tx.append((t, frame, telemetry))

    def _loop(self) -> None:
        try:
            while self._running:
                self._iterate()
        except OSError:
            self._running = False  # pty closed under us (unplug)

    def _iterate(self) -> None:
        now = time.monotonic()
        with self._lock:
            if self._pending_reset:
                self._pending_reset = False
                self._tx.clear()
                self._queue(self.core.boot(), now, telemetry=False)
                self._next_tick = math.inf
        # Receive: bytes become visible after their wire time.
        while self._rx and self._rx[0][0] <= now:
            _, data = self._rx.popleft()
            if not self._stalled:
                reply = self.core.receive(data, self._now_us(now))
                self._queue(reply, now, telemetry=False)
                self._sync_stream(now)
        # Timer ISR: every due sample on the exact grid. A real MCU never lags; when
        # the host OS starved this process, the missed instants are stepped without
        # frames (the host sees a counter gap), so board time stays wall-clock time.
        period_s = self.core.period_us * 1e-6
        while self._next_tick <= now:
            late = now - self._next_tick > max(self.max_lag_s, 20 * period_s)
            self._tick(self._next_tick, report=not late)
            self._next_tick += period_s
            if not self.core.streaming:
                self._next_tick = math.inf
        self._transmit(now)
        # Sleep until the next event.
        wake = min(self._next_tick, now + 0.05)
        if self._tx:
            wake = min(wake, self._tx_due())
        if self._rx:
            wake = min(wake, self._rx[0][0])
        timeout = max(0.0, wake - time.monotonic())
        readable, _, _ = select.select([self._master], [], [], timeout)
        if readable:
            try:
                data = os.read(self._master, 4096)
            except BlockingIOError:
                data = b""
            except OSError:
                data = b""  # no host attached to the slave end right now
            if data:
                t = time.monotonic()
                self._rx_busy = max(self._rx_busy, t) + len(data) * self._byte_s
                self._rx.append((self._rx_busy if self.pace else t, data))

    def _sync_stream(self, now: float) -> None:
        core = self.core
        if core.streaming and math.isinf(self._next_tick):
            dt_s = core.period_us * 1e-6
            if self._plant is None or abs(self._plant.dt_s - dt_s) > 1e-12:
                old = self._plant
                self._plant = Plant(self.motor.model, dt_s)
                if old is not None:
                    # Keep the rotor's motion across a new period (same state layout).
                    self._plant._state[:] = old._state
            self._stream_start = now
            self._next_tick = now
        elif not core.streaming:
            self._next_tick = math.inf

    def _tick(self, t: float, report: bool = True) -> None:
        core = self.core
        plant = self._plant
        assert plant is not None
        now_us = self._now_us(t)
        core.check_watchdog(now_us)
        i = plant.current_a
        if self.motor.sensors.current_noise_a > 0:
            i += float(self._rng.normal(0.0, self.motor.sensors.current_noise_a))
        w = plant.speed_rad_s
        lim = self.motor.limits
        if abs(plant.current_a) > lim.current_max_a:
            core.trip(Fault.OVER_CURRENT)
        if abs(w) > lim.speed_max_rad_s:
            core.trip(Fault.OVER_SPEED)
        v = core.setpoint_v
        cpr = core.info.counts_per_rev
        count = math.floor(plant.position_rad / (2.0 * math.pi) * cpr)
        # Open armature: the terminals show the back-EMF.
        terminal = self.motor.model.params.Ke * w if math.isnan(v) else v
        if report:
            frame = core.telemetry(now_us, count, i, terminal, self.supply_v)
            if not self._stalled:
                self._queue(frame, t, telemetry=True)
        else:
            core.skip_sample()
            self.samples_skipped += 1
        plant.step(None if math.isnan(v) else v)

    def _tx_due(self) -> float:
        t, frame, _ = self._tx[0]
        if not self.pace:
            return t
        return max(t, self._tx_busy) + len(frame) * self._byte_s

    def _transmit(self, now: float) -> None:
        out = bytearray()
        while self._tx and self._tx_due() <= now:
            due = self._tx_due()
            _, frame, _ = self._tx.popleft()
            self._tx_busy = due
            with self._lock:
                if self._corrupt:
                    self._corrupt -= 1
                    raw = bytearray(cobs_decode(frame[:-1]))
                    raw[len(raw) // 2] ^= 0x5A  # payload changed, CRC kept: a CRC error
                    frame = cobs_encode(raw) + b"\x00"
                elif self._truncate:
                    self._truncate -= 1
                    frame = frame[: len(frame) // 2]
            out += frame
            self.frames_sent += 1
        with self._lock:
            if self._inject:
                out += self._inject
                self._inject.clear()
        if out and not self._stalled:
            self._write(bytes(out))

    def _write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self._master, view)
            except BlockingIOError:
                # Nobody reads the other end: a UART sends into the void.
                self.bytes_lost += len(view)
                return
            view = view[n:]
