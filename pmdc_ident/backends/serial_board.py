"""The serial-board backend: a microcontroller speaking the pmdc protocol over pyserial.

:class:`SerialBackend` implements :class:`~pmdc_ident.backends.base.Backend`
for a board running the reference firmware (``firmware/``) or the virtual
board (``pmdc-ident virtual-board``). Wire format: ``docs/serial-protocol.md``.

Time: sample ``k`` of a stream is stamped ``(base + counter) * dt_s``, the
board's sample counter on its own clock, never the host's arrival time. Gaps
in the counter are counted as dropped samples and flag :attr:`Fault.LINK` on
the next sample. Speed is the backward difference of the encoder count over
the counter interval (the mean speed over the previous period; 0 on the first
sample of a session's stream, where the rotor starts at rest; a stream that resumes
after a link loss or a board reset publishes from its second sample, the first only
starts the count: the rotor may be coasting then).

Link loss: a failing port (unplugged), telemetry that stops for
``telemetry_timeout_s``, a board that resets (BOOT frame, counter going back,
or NOT_READY) all make the backend command the motor safe (best effort; the
board's own watchdog opens the armature if nothing gets through), and raise
a one-line :class:`BackendError` from the next :meth:`poll`, once. It then
reopens the port and re-handshakes every ``reconnect_interval_s`` in the
background; commands are refused until it streams again. A protocol version
mismatch or a refused stream rate is fatal (no reconnect). A pseudo-terminal (a
virtual board) is reopened only while it is the same terminal: the kernel hands a
freed ``/dev/pts/N`` to the next program that asks for one (``ros2 launch`` gives
each node a pty), and a reconnecting driver must not write its handshake into
another program's terminal.

Host stalls: the board measured every sample it sent, so a caller that polls late
gets all of them, late (the session judges how late: its ``data_timeout_s``). Only
past ``max_catch_up_s`` of waiting samples (5 s: longer than any session tolerates
by default, shorter than the 10 s the sample topics buffer) are just the newest
returned; the first carries :attr:`Fault.LINK` and :attr:`skipped_samples` counts
the rest, which the driver reports. (A 0.25 s bound dropped the older samples of
every longer stall without a word from the driver: 34 to 434 of an emulated board's
session beside two CPU hogs.)

Host-side keep-alive: :meth:`poll` sends a PING when nothing was written for a
quarter of the board watchdog, so the board watchdog fires when the driver
stops polling (a hung node), not only when the process dies.

The backend is a composition of the parts in :mod:`pmdc_ident.backends.serial_link`:
the port (transport), the handshake, the sample decoder, the hand-over to
:meth:`poll`, the reconnection state machine and the link statistics. It owns the
reader thread that drives them and the commands that the driver sends.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

from pmdc_ident.backends.base import BackendError, Telemetry
from pmdc_ident.backends.serial_link.decoder import SampleDecoder
from pmdc_ident.backends.serial_link.delivery import SampleQueue
from pmdc_ident.backends.serial_link.errors import LinkLostError, error_name, reason, type_name
from pmdc_ident.backends.serial_link.handshake import StreamRequest, negotiate, version_text
from pmdc_ident.backends.serial_link.port import SerialPort
from pmdc_ident.backends.serial_link.reconnect import LinkState, Reconnection
from pmdc_ident.backends.serial_link.stats import LinkCounters, LinkStats, ParserWatch, PingClock
from pmdc_ident.core.enums import SafeMode
from pmdc_ident.core.motors import Limits
from pmdc_ident.protocol import (
    Boot,
    ErrorCode,
    ErrorReply,
    FrameParser,
    HelloAck,
    Message,
    OpenArmature,
    Ping,
    Pong,
    SetVoltage,
    VersionMismatchError,
)
from pmdc_ident.protocol import Telemetry as WireTelemetry

__all__ = ["MAX_CATCH_UP_S", "LinkState", "LinkStats", "SerialBackend"]

# Seconds of a board's samples kept for a caller held up by its host (see above).
MAX_CATCH_UP_S = 5.0


class SerialBackend:
    """A pmdc board on a serial port (see the module docstring for its behaviour)."""

    def __init__(
        self,
        port: str,
        baud: int = 115200,
        limits: Limits | None = None,
        dt_s: float = 0.004,
        safe_mode: SafeMode = SafeMode.OPEN,
        logger: Callable[[str], None] | None = None,
        *,
        telemetry_timeout_s: float | None = None,
        board_watchdog_ms: int = 500,
        handshake_timeout_s: float = 2.5,
        reconnect: bool = True,
        reconnect_interval_s: float = 0.5,
        max_catch_up_s: float = MAX_CATCH_UP_S,
        timeout_name: str = "telemetry_timeout_s",
    ) -> None:
        _check_settings(dt_s, baud, board_watchdog_ms)
        self.port = str(port)
        self.baud = int(baud)
        self._limits = limits if limits is not None else Limits()
        self._dt_s = float(dt_s)
        self._safe_mode = SafeMode(safe_mode)
        self._log = logger or (lambda _line: None)
        self._timeout_s = (
            telemetry_timeout_s if telemetry_timeout_s is not None else max(100 * self._dt_s, 0.5)
        )
        self._timeout_name = timeout_name  # what a user raises (the driver: its watchdog_s)
        self._request = StreamRequest(
            self._dt_s, int(board_watchdog_ms), float(handshake_timeout_s)
        )
        self._serial = SerialPort(self.port, self.baud)
        self._parser = FrameParser()
        self._decoder = SampleDecoder(self._dt_s, self.port, self._log)
        self._queue = SampleQueue(max(1, int(max_catch_up_s / self._dt_s)))
        self._link = Reconnection(enabled=reconnect, interval_s=float(reconnect_interval_s))
        self._counters = LinkCounters()
        self._watch = ParserWatch(self._parser, self.port, self._log)
        self._ping_clock = PingClock()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._last_rx = 0.0
        self._applied_v = math.nan

    # -- Backend protocol ---------------------------------------------------------------
    @property
    def dt_s(self) -> float:
        return self._dt_s

    @property
    def limits(self) -> Limits:
        return self._limits

    @property
    def state(self) -> LinkState:
        return self._link.state

    @property
    def command_v(self) -> float:
        """The last command sent (NaN while the armature is open)."""
        return self._applied_v

    @property
    def board_info(self) -> HelloAck | None:
        """The board's HELLO_ACK of the current session."""
        return self._decoder.info

    @property
    def skipped_samples(self) -> int:
        """Samples left out because the host fell behind (see :meth:`poll`)."""
        return self._queue.skipped

    def start(self) -> None:
        """Open the port, handshake and start the stream; raises BackendError."""
        alive = self._thread is not None and self._thread.is_alive()
        if self.state is LinkState.STREAMING or (alive and self.state is LinkState.LOST):
            return  # streaming, or reconnecting in the background
        if alive:  # FAILED: retire the old reader before trying again
            self._stop.set()
            self._thread.join(timeout=3.0)  # type: ignore[union-attr]
        self._stop.clear()
        try:
            self._connect()
        except LinkLostError as exc:
            self._link.failed()
            self._counters.last_error = str(exc)
            raise BackendError(str(exc)) from None
        self._thread = threading.Thread(target=self._run, name="serial-board", daemon=True)
        self._thread.start()

    def command_voltage(self, voltage_v: float) -> float:
        try:
            v = float(voltage_v)
        except (TypeError, ValueError):
            msg = f"voltage command must be a number, got {voltage_v!r}"
            raise BackendError(msg) from None
        if not math.isfinite(v):
            self.make_safe()
            msg = f"voltage command {v} refused (not finite); motor kept safe"
            raise BackendError(msg)
        vmax = self._limits.voltage_max_v
        info = self._decoder.info
        if info is not None:
            vmax = min(vmax, info.voltage_max_v, info.supply_nominal_v)
        v = max(-vmax, min(vmax, v))
        self._require_streaming()
        self._serial.send(SetVoltage(int(round(v * 1000.0))))
        self._applied_v = v
        return v

    def open_armature(self) -> None:
        self._require_streaming()
        self._serial.send(OpenArmature())
        self._applied_v = math.nan

    def make_safe(self) -> None:
        msg: Message = OpenArmature() if self._safe_mode is SafeMode.OPEN else SetVoltage(0)
        try:
            self._serial.send(msg)
        except Exception:  # noqa: BLE001 - make_safe never raises; the board watchdog backs it
            pass
        self._applied_v = math.nan if self._safe_mode is SafeMode.OPEN else 0.0

    def poll(self) -> list[Telemetry]:
        """Samples received since the last call; raises BackendError once per link loss."""
        if self.state is LinkState.STREAMING:
            now = time.monotonic()
            if now - self._serial.last_write_s > self._request.board_watchdog_ms * 2.5e-4:
                try:
                    self._serial.send(Ping(self._ping_clock.token()))
                except BackendError:
                    pass  # the reader thread reports the failure
        return self._queue.take()

    def close(self) -> None:
        if self.state is LinkState.CLOSED and not self._serial.is_open:
            return
        self.make_safe()
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        self._serial.close()
        self._link.closed()

    def __enter__(self) -> SerialBackend:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- diagnostics ----------------------------------------------------------------------
    @property
    def link_stats(self) -> LinkStats:
        p = self._parser.stats
        info = self._decoder.info
        return LinkStats(
            state=self.state,
            port=self.port,
            baud=self.baud,
            period_us=self._request.period_us,
            samples=self._decoder.samples_total,
            dropped_samples=self._decoder.dropped,
            frames_ok=p.frames_ok,
            crc_errors=p.crc_errors,
            framing_errors=p.framing_errors,
            oversize_frames=p.oversize_frames,
            bad_messages=p.bad_messages,
            board_errors=self._counters.board_errors,
            board_resets=self._counters.board_resets,
            reconnects=self._counters.reconnects,
            ping_rtt_s=self._ping_clock.rtt_s,
            firmware_version=info.firmware_version if info is not None else -1,
            last_error=self._counters.last_error,
        )

    # -- the link ---------------------------------------------------------------------------
    def _require_streaming(self) -> None:
        if self.state is not LinkState.STREAMING:
            msg = f"serial board on {self.port} is not streaming ({self.state.value}); "
            msg += "command not sent"
            raise BackendError(msg)

    def _connect(self) -> None:
        """Open, handshake, start the stream. Raises LinkLostError."""
        self._serial.open()
        try:
            info, first = negotiate(self._serial, self._parser, self._request, self._stop)
            self._begin_stream(info)
            for t in first:
                self._on_telemetry(t)
        except BaseException:
            self._serial.close()
            raise

    def _begin_stream(self, info: HelloAck) -> None:
        now = time.monotonic()
        self._decoder.begin(info, now, self._link.lost_at)
        self._last_rx = now
        self._serial.last_write_s = now
        self._applied_v = math.nan
        self._link.streaming()

    def _on_telemetry(self, t: WireTelemetry) -> Telemetry | None:
        sample = self._decoder.decode(t)
        if sample is not None:
            self._queue.put(sample)
        self._last_rx = time.monotonic()
        return sample

    def _on_message(self, item: Message | VersionMismatchError) -> None:
        if isinstance(item, WireTelemetry):
            self._on_telemetry(item)
        elif isinstance(item, Pong):
            self._ping_clock.answered(item.token)
        elif isinstance(item, Boot):
            self._counters.board_resets += 1
            raise LinkLostError(f"board on {self.port} reset (it sent BOOT); re-handshaking")
        elif isinstance(item, VersionMismatchError):
            raise LinkLostError(version_text(self.port, item.version), fatal=True)
        elif isinstance(item, ErrorReply):
            self._counters.board_errors += 1
            if item.code == ErrorCode.NOT_READY:
                self._counters.board_resets += 1
                msg = f"board on {self.port} lost its session (NOT_READY): reset? re-handshaking"
                raise LinkLostError(msg)
            name = type_name(item.refused_type)
            self._log(f"serial board {self.port}: board refused {name} ({error_name(item.code)})")

    # -- the reader thread ---------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                if self.state is LinkState.STREAMING:
                    self._stream_once()
                elif self.state is LinkState.LOST:
                    self._try_reconnect()
                else:
                    self._stop.wait(0.05)
            except LinkLostError as exc:
                self._lost(str(exc), exc.fatal)
            except Exception as exc:  # noqa: BLE001 - never let the reader die silently
                self._lost(f"serial board {self.port}: internal error: {reason(exc)}", False)

    def _stream_once(self) -> None:
        for _seq, item in self._parser.feed(self._serial.read()):
            self._on_message(item)
        now = time.monotonic()
        last_error = self._watch.new_errors(now)
        if last_error is not None:
            self._decoder.flag_link()
            self._counters.last_error = last_error
        silent = now - self._last_rx
        if silent > self._timeout_s:
            msg = (
                f"no telemetry from the board on {self.port} for {silent:.2f} s "
                f"({silent / self._dt_s:.0f} sample periods; timeout {self._timeout_s:g} s, "
                f"{self._timeout_name})"
            )
            raise LinkLostError(msg)

    def _lost(self, message: str, fatal: bool) -> None:
        if self._stop.is_set():
            return
        self.make_safe()
        self._serial.close()
        self._counters.last_error = message
        report = self._link.lose(message, time.monotonic(), fatal=fatal)
        if report is not None:
            self._queue.report(report)  # raised once, by the next poll() (one line)

    def _try_reconnect(self) -> None:
        wait_s = self._link.wait_s(time.monotonic())
        if wait_s > 0.0:
            self._stop.wait(min(0.05, wait_s))
            return
        try:
            self._connect()
        except LinkLostError as exc:
            if exc.fatal:
                raise
            self._counters.last_error = str(exc)
            return
        self._counters.reconnects += 1
        self._log(
            f"serial board: reconnected to {self.port}; streaming again with the armature open"
        )


def _check_settings(dt_s: float, baud: int, board_watchdog_ms: int) -> None:
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        msg = f"sample period dt_s must be a positive number of seconds, got {dt_s}"
        raise BackendError(msg)
    if int(baud) <= 0:
        msg = f"baud must be a positive integer, got {baud}"
        raise BackendError(msg)
    if not 20 <= int(board_watchdog_ms) <= 65535:
        msg = f"board_watchdog_ms must be within 20..65535, got {board_watchdog_ms}"
        raise BackendError(msg)
