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

Host stalls: if the caller polls so late that more than ``max_catch_up_s`` of
samples wait, only the newest are returned; the first carries
:attr:`Fault.LINK` and :attr:`skipped_samples` counts the rest (the policy of
the simulated backend), so published samples never lag far behind the board.

Host-side keep-alive: :meth:`poll` sends a PING when nothing was written for a
quarter of the board watchdog, so the board watchdog fires when the driver
stops polling (a hung node), not only when the process dies.
"""

from __future__ import annotations

import collections
import enum
import math
import os
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import serial

from pmdc_ident.backends.base import BackendError, Telemetry
from pmdc_ident.core.enums import Fault, SafeMode
from pmdc_ident.core.motors import Limits
from pmdc_ident.protocol import (
    PROTOCOL_VERSION,
    Ack,
    Boot,
    ErrorCode,
    ErrorReply,
    FrameParser,
    Hello,
    HelloAck,
    Message,
    MsgType,
    OpenArmature,
    Ping,
    Pong,
    SetVoltage,
    StartStream,
    VersionMismatchError,
    frame_message,
)
from pmdc_ident.protocol import Telemetry as WireTelemetry
from pmdc_ident.protocol.messages import NOT_MEASURED

__all__ = ["LinkState", "LinkStats", "SerialBackend"]

WRITE_STALL_S = 0.5  # a port that accepts no byte for this long (while waited for) failed

_STICKY_REPORTED = Fault.OVER_CURRENT | Fault.OVER_SPEED | Fault.WATCHDOG | Fault.BAD_COMMAND


class LinkState(enum.Enum):
    CLOSED = "closed"
    STREAMING = "streaming"
    LOST = "lost"  # reconnecting in the background
    FAILED = "failed"  # will not reconnect (version mismatch, refused rate, closed)


@dataclass(frozen=True)
class LinkStats:
    """Link health for /diagnostics."""

    state: LinkState
    port: str
    baud: int
    period_us: int
    samples: int
    dropped_samples: int
    frames_ok: int
    crc_errors: int
    framing_errors: int
    oversize_frames: int
    bad_messages: int
    board_errors: int
    board_resets: int
    reconnects: int
    ping_rtt_s: float
    firmware_version: int
    last_error: str

    def as_strings(self) -> dict[str, str]:
        """Key/value pairs for a diagnostic_msgs/DiagnosticStatus."""
        out = {}
        for name in self.__dataclass_fields__:
            value = getattr(self, name)
            out[name] = value.value if isinstance(value, LinkState) else str(value)
        return out


class _LinkLostError(Exception):
    """Internal: the link failed; message and whether reconnecting makes sense."""

    def __init__(self, message: str, fatal: bool = False) -> None:
        super().__init__(message)
        self.fatal = fatal


def _reason(exc: BaseException) -> str:
    """A short reason for a pyserial/OS error, without pyserial's repeated port name."""
    code = getattr(exc, "errno", None)
    if isinstance(code, int) and code > 0:
        return os.strerror(code)
    text = str(getattr(exc, "strerror", None) or str(exc) or type(exc).__name__)
    if "returned no data" in text:  # pyserial's wording when the device vanished
        return "device disconnected"
    if "Could not configure port" in text:
        detail = text.split("'")[1] if text.count("'") >= 2 else text
        return f"not a serial port ({detail})"
    return text.splitlines()[0]


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
        max_catch_up_s: float = 0.25,
        timeout_name: str = "telemetry_timeout_s",
    ) -> None:
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            msg = f"sample period dt_s must be a positive number of seconds, got {dt_s}"
            raise BackendError(msg)
        if int(baud) <= 0:
            msg = f"baud must be a positive integer, got {baud}"
            raise BackendError(msg)
        if not 20 <= int(board_watchdog_ms) <= 65535:
            msg = f"board_watchdog_ms must be within 20..65535, got {board_watchdog_ms}"
            raise BackendError(msg)
        self.port = str(port)
        self.baud = int(baud)
        self._limits = limits if limits is not None else Limits()
        self._dt_s = float(dt_s)
        self._period_us = int(round(self._dt_s * 1e6))
        self._safe_mode = SafeMode(safe_mode)
        self._log = logger or (lambda _line: None)
        self._timeout_s = (
            telemetry_timeout_s if telemetry_timeout_s is not None else max(100 * self._dt_s, 0.5)
        )
        self._timeout_name = timeout_name  # what a user raises (the driver: its watchdog_s)
        self._board_wd_ms = int(board_watchdog_ms)
        self._handshake_s = float(handshake_timeout_s)
        self._reconnect = reconnect
        self._reconnect_s = float(reconnect_interval_s)

        self._ser: serial.Serial | None = None
        self._write_lock = threading.Lock()
        self._lock = threading.Lock()
        self._max_catch_up = max(1, int(max_catch_up_s / self._dt_s))
        self._samples: collections.deque[Telemetry] = collections.deque()
        self.skipped_samples = 0  # left out because the host fell behind (see poll)
        self._pending_error: str | None = None
        self._state = LinkState.CLOSED
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._parser = FrameParser()
        self._seq = 0
        self._info: HelloAck | None = None
        self._last_write = 0.0
        self._last_rx = 0.0
        self._next_attempt = 0.0
        self._last_error = ""
        self._ping_sent: dict[int, float] = {}
        self._ping_rtt_s = math.nan
        # stream bookkeeping
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
        self._lost_at = 0.0
        # statistics
        self._samples_total = 0
        self._dropped = 0
        self._board_errors = 0
        self._board_resets = 0
        self._reconnects = 0
        self._pty: tuple[int, int] | None = None  # the pseudo-terminal first opened
        self._seen_errors = 0
        self._last_link_log = 0.0
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
        return self._state

    @property
    def command_v(self) -> float:
        """The last command sent (NaN while the armature is open)."""
        return self._applied_v

    @property
    def board_info(self) -> HelloAck | None:
        """The board's HELLO_ACK of the current session."""
        return self._info

    def start(self) -> None:
        """Open the port, handshake and start the stream; raises BackendError."""
        alive = self._thread is not None and self._thread.is_alive()
        if self._state is LinkState.STREAMING or (alive and self._state is LinkState.LOST):
            return  # streaming, or reconnecting in the background
        if alive:  # FAILED: retire the old reader before trying again
            self._stop.set()
            self._thread.join(timeout=3.0)  # type: ignore[union-attr]
        self._stop.clear()
        try:
            self._connect()
        except _LinkLostError as exc:
            self._state = LinkState.FAILED
            self._last_error = str(exc)
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
        if self._info is not None:
            vmax = min(vmax, self._info.voltage_max_v, self._info.supply_nominal_v)
        v = max(-vmax, min(vmax, v))
        self._require_streaming()
        self._send(SetVoltage(int(round(v * 1000.0))))
        self._applied_v = v
        return v

    def open_armature(self) -> None:
        self._require_streaming()
        self._send(OpenArmature())
        self._applied_v = math.nan

    def make_safe(self) -> None:
        msg: Message = OpenArmature() if self._safe_mode is SafeMode.OPEN else SetVoltage(0)
        try:
            self._send(msg)
        except Exception:  # noqa: BLE001 - make_safe never raises; the board watchdog backs it
            pass
        self._applied_v = math.nan if self._safe_mode is SafeMode.OPEN else 0.0

    def poll(self) -> list[Telemetry]:
        """Samples received since the last call; raises BackendError once per link loss."""
        if self._state is LinkState.STREAMING:
            now = time.monotonic()
            if now - self._last_write > self._board_wd_ms * 2.5e-4:
                try:
                    self._ping()
                except BackendError:
                    pass  # the reader thread reports the failure
        with self._lock:
            out = list(self._samples)
            self._samples.clear()
            if len(out) > self._max_catch_up:
                # The host fell behind: deliver only the newest max_catch_up_s, as the
                # simulated backend does, so published samples never lag far behind.
                skip = len(out) - self._max_catch_up
                out = out[skip:]
                self.skipped_samples += skip
                out[0] = replace(out[0], faults=out[0].faults | Fault.LINK)
            error = self._pending_error
            if error is not None and not out:
                self._pending_error = None
        if error is not None and not out:
            raise BackendError(error)
        return out

    def close(self) -> None:
        if self._state is LinkState.CLOSED and self._ser is None:
            return
        self.make_safe()
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self._thread = None
        self._close_port()
        self._state = LinkState.CLOSED

    def __enter__(self) -> SerialBackend:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- diagnostics ----------------------------------------------------------------------
    @property
    def link_stats(self) -> LinkStats:
        p = self._parser.stats
        info = self._info
        return LinkStats(
            state=self._state,
            port=self.port,
            baud=self.baud,
            period_us=self._period_us,
            samples=self._samples_total,
            dropped_samples=self._dropped,
            frames_ok=p.frames_ok,
            crc_errors=p.crc_errors,
            framing_errors=p.framing_errors,
            oversize_frames=p.oversize_frames,
            bad_messages=p.bad_messages,
            board_errors=self._board_errors,
            board_resets=self._board_resets,
            reconnects=self._reconnects,
            ping_rtt_s=self._ping_rtt_s,
            firmware_version=info.firmware_version if info is not None else -1,
            last_error=self._last_error,
        )

    # -- writing -----------------------------------------------------------------------------
    def _require_streaming(self) -> None:
        if self._state is not LinkState.STREAMING:
            msg = f"serial board on {self.port} is not streaming ({self._state.value}); "
            msg += "command not sent"
            raise BackendError(msg)

    def _send(self, msg: Message) -> int:
        ser = self._ser
        if ser is None:
            text = f"serial port {self.port} is not open"
            raise BackendError(text)
        with self._write_lock:
            self._seq = (self._seq + 1) & 0xFF
            seq = self._seq
            try:
                self._write_all(ser, frame_message(msg, seq))
            except (serial.SerialException, OSError, TypeError, AttributeError, ValueError) as exc:
                text = f"serial port {self.port} write failed: {_reason(exc)}"
                raise BackendError(text) from None
            self._last_write = time.monotonic()
        return seq

    def _write_all(self, ser: serial.Serial, data: bytes) -> None:
        """Write every byte; time out only while the port itself refuses bytes.

        Not ``ser.write``: pyserial 3.5 raises 'Write timeout' after a complete write
        whenever the call as a whole took longer than its timeout, which a host starved
        of CPU for half a second (a busy machine) turns into a lost link. Here the
        port's file descriptor (non-blocking, as pyserial opens it) takes what it can,
        and only a port that takes nothing for ``WRITE_STALL_S`` of waiting is a
        failure (a wedged adapter)."""
        fd = ser.fileno()
        view = memoryview(data)
        while view:
            try:
                n = os.write(fd, view)
            except BlockingIOError:
                n = 0
            view = view[n:]
            if view and not select.select([], [fd], [], WRITE_STALL_S)[1]:
                msg = f"the port took no byte for {WRITE_STALL_S:g} s"
                raise serial.SerialTimeoutException(msg)

    def _ping(self) -> None:
        token = int(time.monotonic_ns() // 1000) & 0xFFFFFFFF
        with self._lock:  # the reader thread pops answered pings
            self._ping_sent[token] = time.monotonic()
            if len(self._ping_sent) > 16:
                self._ping_sent.pop(next(iter(self._ping_sent)))
        self._send(Ping(token))

    # -- connecting --------------------------------------------------------------------------
    def _close_port(self) -> None:
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:  # noqa: BLE001 - closing a dead port may fail any way
                pass

    def _connect(self) -> None:
        """Open, handshake, start the stream. Raises _LinkLostError."""
        self._close_port()
        pty = _pty_identity(self.port)
        if self._pty is None:
            self._pty = pty
        elif pty is not None and pty != self._pty:
            msg = (
                f"{self.port} is now another program's terminal (the pseudo-terminal "
                "number was reused after the board closed it)"
            )
            raise _LinkLostError(msg, fatal=True)
        try:
            self._ser = serial.Serial(self.port, self.baud, timeout=0.02, exclusive=True)
        except (serial.SerialException, OSError, ValueError) as exc:
            msg = f"cannot open serial port {self.port!r}: {_reason(exc)}"
            raise _LinkLostError(msg) from None
        try:
            self._handshake()
        except BaseException:
            self._close_port()
            raise

    def _read(self) -> bytes:
        ser = self._ser
        if ser is None:
            msg = f"serial port {self.port} is closed"
            raise _LinkLostError(msg)
        try:
            return bytes(ser.read(max(1, ser.in_waiting)))
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            msg = f"serial port {self.port} failed: {_reason(exc)} (board unplugged?)"
            raise _LinkLostError(msg) from None

    def _handshake(self) -> None:
        ser = self._ser
        assert ser is not None
        self._parser.reset()
        try:
            ser.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            msg = f"serial port {self.port} failed: {_reason(exc)}"
            raise _LinkLostError(msg) from None
        deadline = time.monotonic() + self._handshake_s
        info: HelloAck | None = None
        start_seq = -1
        next_hello = 0.0
        streaming = False
        while not streaming:
            now = time.monotonic()
            if self._stop.is_set():
                msg = f"serial board on {self.port}: closed during the handshake"
                raise _LinkLostError(msg)
            if now > deadline:
                what = "HELLO" if info is None else "START_STREAM"
                msg = (
                    f"no answer to {what} from a pmdc board on {self.port} at {self.baud} baud "
                    f"within {self._handshake_s:g} s (wrong port or baud, or no firmware?)"
                )
                raise _LinkLostError(msg)
            if info is None and now >= next_hello:
                self._send_or_lost(Hello(PROTOCOL_VERSION))
                next_hello = now + 0.25
            for seq, item in self._parser.feed(self._read()):
                if isinstance(item, VersionMismatchError):
                    raise _LinkLostError(self._version_text(item.version), fatal=True)
                if isinstance(item, HelloAck) and info is None:
                    if item.protocol_version != PROTOCOL_VERSION:
                        raise _LinkLostError(self._version_text(item.protocol_version), True)
                    info = item
                    if self._period_us < item.min_period_us:
                        raise _LinkLostError(self._rate_text(item.min_period_us), fatal=True)
                    start_seq = self._send_or_lost(StartStream(self._period_us, self._board_wd_ms))
                elif isinstance(item, ErrorReply) and seq == start_seq:
                    if item.code == ErrorCode.RATE_TOO_HIGH:
                        raise _LinkLostError(self._rate_text(item.detail), fatal=True)
                    msg = f"board refused START_STREAM ({_error_name(item.code)})"
                    raise _LinkLostError(msg)
                elif isinstance(item, Ack) and seq == start_seq:
                    streaming = True
                    self._begin_stream(info)
                elif streaming and isinstance(item, WireTelemetry):
                    self._on_telemetry(item)

    def _send_or_lost(self, msg: Message) -> int:
        try:
            return self._send(msg)
        except BackendError as exc:
            raise _LinkLostError(str(exc)) from None

    def _version_text(self, version: int) -> str:
        return (
            f"board on {self.port} speaks pmdc protocol v{version}; this host speaks "
            f"v{PROTOCOL_VERSION}: flash matching firmware or update pmdc_ident"
        )

    def _rate_text(self, min_us: int) -> str:
        return (
            f"a {1.0 / self._dt_s:g} Hz stream (dt_s = {self._dt_s * 1e3:g} ms) is faster than "
            f"the board streams at {self.baud} baud (at most {1e6 / min_us:.0f} Hz, period >= "
            f"{min_us / 1e3:g} ms): raise the baud or lower the rate"
        )

    def _begin_stream(self, info: HelloAck | None) -> None:
        assert info is not None
        now = time.monotonic()
        with self._lock:
            self._info = info
            if self._samples_total and self._lost_at:
                # Continue the time axis across the outage, on the board's grid.
                gap = int(round((now - self._lost_at) / self._dt_s))
                self._next_index += max(0, gap)
            self._base = self._next_index
            self._last_counter = None
            self._counter_acc = 0
            self._pos_offset_rad = self._last_position
            self._pos_counts = 0
            self._resumed = self._samples_total > 0
            self._last_faults = Fault.NONE
            self._last_rx = now
            self._last_write = now
            self._applied_v = math.nan
            self._state = LinkState.STREAMING

    # -- receiving --------------------------------------------------------------------------
    def _on_telemetry(self, t: WireTelemetry) -> None:
        info = self._info
        assert info is not None
        if self._last_counter is None:
            step = 1
            delta = 0
            self._last_count = t.encoder_count
            if self._resumed:
                # A stream resumed after a link loss or a board reset: the rotor may still
                # turn (it coasts while the board reboots), and one count gives no speed.
                # Publishing 0 would be a false reading (a 265 rad/s coast read 0 for one
                # sample): this sample only starts the count, the next is the first out.
                self._resumed = False
                self._last_counter = t.counter
                self._last_rx = time.monotonic()
                return
        else:
            step = (t.counter - self._last_counter) & 0xFFFFFFFF
            if step == 0 or step >= 0x80000000:
                msg = (
                    f"board sample counter went back ({self._last_counter} -> {t.counter}): "
                    "board reset?"
                )
                raise _LinkLostError(msg)
            delta = ((t.encoder_count - self._last_count + 2**31) % 2**32) - 2**31
        if step > 1 and self._last_counter is not None:
            self._dropped += step - 1
            self._link_flag = True
        self._counter_acc += step if self._last_counter is not None else 0
        self._last_counter = t.counter
        self._last_count = t.encoder_count
        self._pos_counts += delta
        rad_per_count = 2.0 * math.pi / info.counts_per_rev
        index = self._base + self._counter_acc
        position = self._pos_offset_rad + self._pos_counts * rad_per_count
        speed = delta * rad_per_count / (step * self._dt_s)
        faults = Fault(t.faults & 0x7F)
        if self._link_flag:
            faults |= Fault.LINK
            self._link_flag = False
        new = (faults & ~self._last_faults) & _STICKY_REPORTED
        if new:
            names = "|".join(f.name or "?" for f in Fault if f and f in new)
            self._log(f"serial board {self.port}: board reports {names} (armature opened)")
        self._last_faults = faults
        # The LSBs travel as float32: 7 significant digits are all they carry.
        lsb_v = float(f"{info.voltage_lsb_v:.7g}")
        lsb_a = float(f"{info.current_lsb_a:.7g}")
        sample = Telemetry(
            sample_index=index,
            time_s=index * self._dt_s,
            current_a=math.nan if t.current == NOT_MEASURED else t.current * lsb_a,
            position_rad=position,
            speed_rad_s=speed,
            voltage_cmd_v=math.nan if t.applied_v == NOT_MEASURED else t.applied_v * lsb_v,
            terminal_voltage_v=math.nan if t.terminal_v == NOT_MEASURED else t.terminal_v * lsb_v,
            supply_voltage_v=math.nan if t.supply_v == NOT_MEASURED else t.supply_v * lsb_v,
            faults=faults,
        )
        with self._lock:
            self._samples.append(sample)
            self._samples_total += 1
            self._next_index = index + 1
            self._last_position = position
        self._last_rx = time.monotonic()

    def _dispatch(self, seq: int, item: Message | VersionMismatchError) -> None:
        if isinstance(item, WireTelemetry):
            self._on_telemetry(item)
        elif isinstance(item, Pong):
            with self._lock:
                sent = self._ping_sent.pop(item.token, None)
            if sent is not None:
                self._ping_rtt_s = time.monotonic() - sent
        elif isinstance(item, Boot):
            self._board_resets += 1
            raise _LinkLostError(f"board on {self.port} reset (it sent BOOT); re-handshaking")
        elif isinstance(item, VersionMismatchError):
            raise _LinkLostError(self._version_text(item.version), fatal=True)
        elif isinstance(item, ErrorReply):
            self._board_errors += 1
            if item.code == ErrorCode.NOT_READY:
                self._board_resets += 1
                msg = f"board on {self.port} lost its session (NOT_READY): reset? re-handshaking"
                raise _LinkLostError(msg)
            name = _type_name(item.refused_type)
            self._log(f"serial board {self.port}: board refused {name} ({_error_name(item.code)})")

    def _check_link_errors(self, now: float) -> None:
        errors = self._parser.stats.errors
        if errors != self._seen_errors:
            self._link_flag = True
            if now - self._last_link_log >= 1.0:
                s = self._parser.stats
                self._log(
                    f"serial board {self.port}: link errors (crc {s.crc_errors}, framing "
                    f"{s.framing_errors}, oversize {s.oversize_frames}, bad {s.bad_messages} "
                    f"so far; last: {self._parser.last_error})"
                )
                self._last_link_log = now
            self._seen_errors = errors
            self._last_error = self._parser.last_error

    # -- the reader thread ---------------------------------------------------------------------
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                if self._state is LinkState.STREAMING:
                    self._stream_once()
                elif self._state is LinkState.LOST:
                    self._try_reconnect()
                else:
                    self._stop.wait(0.05)
            except _LinkLostError as exc:
                self._lost(str(exc), exc.fatal)
            except Exception as exc:  # noqa: BLE001 - never let the reader die silently
                self._lost(f"serial board {self.port}: internal error: {_reason(exc)}", False)

    def _stream_once(self) -> None:
        data = self._read()
        for seq, item in self._parser.feed(data):
            self._dispatch(seq, item)
        now = time.monotonic()
        self._check_link_errors(now)
        silent = now - self._last_rx
        if silent > self._timeout_s:
            msg = (
                f"no telemetry from the board on {self.port} for {silent:.2f} s "
                f"({silent / self._dt_s:.0f} sample periods; timeout {self._timeout_s:g} s, "
                f"{self._timeout_name})"
            )
            raise _LinkLostError(msg)

    def _lost(self, message: str, fatal: bool) -> None:
        if self._stop.is_set():
            return
        was = self._state
        self.make_safe()
        self._close_port()
        self._last_error = message
        self._lost_at = time.monotonic()
        if fatal or not self._reconnect:
            self._state = LinkState.FAILED
            tail = "; motor commanded safe; not reconnecting"
        else:
            self._state = LinkState.LOST
            tail = "; motor commanded safe; reconnecting"
            self._next_attempt = self._lost_at + self._reconnect_s
        if was is LinkState.STREAMING or fatal:
            # Reported once, by the next poll() (the caller logs it: one line).
            with self._lock:
                self._pending_error = message + tail

    def _try_reconnect(self) -> None:
        now = time.monotonic()
        if now < self._next_attempt:
            self._stop.wait(min(0.05, self._next_attempt - now))
            return
        self._next_attempt = now + self._reconnect_s
        try:
            self._connect()
        except _LinkLostError as exc:
            if exc.fatal:
                raise
            self._last_error = str(exc)
            return
        self._reconnects += 1
        self._log(
            f"serial board: reconnected to {self.port}; streaming again with the armature open"
        )


def _pty_identity(port: str) -> tuple[int, int] | None:
    """(device, inode change time) of a pseudo-terminal; ``None`` for anything else.

    A reallocated ``/dev/pts/N`` has the same device number but a new inode."""
    path = os.path.realpath(port)
    if not path.startswith("/dev/pts/"):
        return None
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_rdev, st.st_ctime_ns


def _error_name(code: int) -> str:
    try:
        return ErrorCode(code).name
    except ValueError:
        return f"error {code}"


def _type_name(kind: int) -> str:
    try:
        return MsgType(kind).name
    except ValueError:
        return f"type 0x{kind:02x}"
