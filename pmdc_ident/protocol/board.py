"""The board side of the protocol as pure logic (no I/O, no clock of its own).

:class:`BoardCore` is what a microcontroller runs between its UART and its
H-bridge: handshake, stream-rate negotiation, command handling with clamping,
the board-side watchdog and telemetry framing. The Python virtual board wraps
it around the motor model; ``firmware/protocol/pmdc_protocol.c`` implements the
same state machine in C, and the tests check both produce identical bytes.

Times are board microseconds (``now_us``), handed in by the caller.
"""

from __future__ import annotations

import math
import struct

from pmdc_ident.core.enums import Fault
from pmdc_ident.protocol.codec import encode_frame
from pmdc_ident.protocol.messages import (
    MESSAGE_TYPES,
    NOT_MEASURED,
    PROTOCOL_VERSION,
    Ack,
    Boot,
    ErrorCode,
    ErrorReply,
    HelloAck,
    Message,
    MsgType,
    Pong,
    Telemetry,
    encode_message,
)
from pmdc_ident.protocol.parser import FrameParser

__all__ = ["DEFAULT_WATCHDOG_MS", "STICKY_FAULTS", "BoardCore"]

DEFAULT_WATCHDOG_MS = 500


# Cleared by the next valid drive command (SET_VOLTAGE / SET_DUTY / OPEN).
STICKY_FAULTS = Fault.OVER_CURRENT | Fault.OVER_SPEED | Fault.WATCHDOG


def _q(value: float, lsb: float) -> int:
    """Round to int16 counts of ``lsb``, saturating short of NOT_MEASURED."""
    if math.isnan(value):
        return NOT_MEASURED
    return max(-32767, min(32767, int(math.floor(value / lsb + 0.5))))


class BoardCore:
    """Protocol state machine of the board. Feed bytes in, send the bytes it returns."""

    def __init__(
        self,
        *,
        min_period_us: int,
        counts_per_rev: int,
        current_lsb_a: float,
        voltage_lsb_v: float,
        supply_nominal_v: float,
        voltage_max_v: float,
        capabilities: int,
        firmware_version: int = 1,
        protocol_version: int = PROTOCOL_VERSION,
    ) -> None:
        # Stored as float32 so the Python and C boards round identically.
        f32 = struct.Struct("<f")
        self.info = HelloAck(
            protocol_version,
            capabilities,
            firmware_version,
            min_period_us,
            counts_per_rev,
            *(f32.unpack(f32.pack(x))[0] for x in (current_lsb_a, voltage_lsb_v)),
            *(f32.unpack(f32.pack(x))[0] for x in (supply_nominal_v, voltage_max_v)),
        )
        self.parser = FrameParser()
        self.boot()

    # -- state ------------------------------------------------------------------
    def boot(self) -> bytes:
        """Power-up/reset: stream off, armature open, not ready; returns the BOOT frame."""
        self.ready = False
        self.streaming = False
        self.period_us = 0
        self.watchdog_ms = DEFAULT_WATCHDOG_MS
        self.counter = 0
        self.setpoint_mv: int | None = None  # None: armature open
        self.faults = 0
        self.last_host_us = 0
        self._seen_errors = self.parser.stats.errors
        return encode_frame(
            encode_message(Boot(self.info.protocol_version, self.info.firmware_version))
        )

    @property
    def setpoint_v(self) -> float:
        """Voltage to hold over the next sample; NaN while the armature is open."""
        return math.nan if self.setpoint_mv is None else self.setpoint_mv / 1000.0

    def trip(self, fault_bit: int) -> None:
        """A protection tripped: open the armature and latch the fault bit."""
        self.setpoint_mv = None
        self.faults |= fault_bit

    # -- host -> board ------------------------------------------------------------
    def receive(self, data: bytes, now_us: int) -> bytes:
        """Process received bytes; returns the reply bytes to transmit."""
        out = bytearray()
        # Parse raw payloads ourselves: the board must answer even bad bodies.
        for seq, item in self._payloads(data):
            self.last_host_us = now_us
            out += self._handle(item, seq, now_us)
        if self.parser.stats.errors != self._seen_errors:
            self.faults |= Fault.LINK
            self._seen_errors = self.parser.stats.errors
        return bytes(out)

    def _payloads(self, data: bytes) -> list[tuple[int, bytes]]:
        return [(p[1], p) for p in self.parser.feed_payloads(data)]

    def _handle(self, payload: bytes, seq: int, now_us: int) -> bytes:
        kind = payload[0]
        cls = MESSAGE_TYPES.get(kind)
        if cls is None or kind >= 0x80:
            return self._reply(ErrorReply(kind, ErrorCode.UNKNOWN_TYPE, 0), seq)
        body = payload[2:]
        if len(body) != struct.calcsize("<" + cls.FORMAT):
            return self._reply(ErrorReply(kind, ErrorCode.BAD_LENGTH, len(body)), seq)
        msg = cls(*struct.unpack("<" + cls.FORMAT, body))
        if kind == MsgType.HELLO:
            # A new session: stop, open the armature, then describe the board.
            self.streaming = False
            self.setpoint_mv = None
            self.faults = 0
            self.ready = msg.host_version == self.info.protocol_version  # type: ignore[attr-defined]
            return self._reply(self.info, seq)
        if kind == MsgType.PING:
            return self._reply(Pong(msg.token, now_us & 0xFFFFFFFF), seq)  # type: ignore[attr-defined]
        if not self.ready:
            return self._reply(ErrorReply(kind, ErrorCode.NOT_READY, 0), seq)
        if kind == MsgType.START_STREAM:
            period = msg.period_us  # type: ignore[attr-defined]
            if period < self.info.min_period_us:
                err = ErrorReply(kind, ErrorCode.RATE_TOO_HIGH, self.info.min_period_us)
                return self._reply(err, seq)
            self.period_us = period
            self.watchdog_ms = msg.watchdog_ms or DEFAULT_WATCHDOG_MS  # type: ignore[attr-defined]
            self.counter = 0
            self.streaming = True
        elif kind == MsgType.STOP_STREAM:
            self.streaming = False
        elif kind == MsgType.SET_VOLTAGE:
            self._drive_mv(msg.millivolts)  # type: ignore[attr-defined]
        elif kind == MsgType.SET_DUTY:
            duty = msg.duty_q15  # type: ignore[attr-defined]
            if duty < -32767:
                self.trip(Fault.BAD_COMMAND)
                return self._reply(ErrorReply(kind, ErrorCode.BAD_VALUE, duty & 0xFFFF), seq)
            supply_mv = int(self.info.supply_nominal_v * 1000.0 + 0.5)
            product = duty * supply_mv  # C: int64 product, division truncating toward 0
            self._drive_mv(abs(product) // 32767 * (1 if product >= 0 else -1))
        elif kind == MsgType.OPEN_ARMATURE:
            self.setpoint_mv = None
            self.faults &= ~(STICKY_FAULTS | Fault.CLAMPED | Fault.BAD_COMMAND)
        return self._reply(Ack(kind), seq)

    def _drive_mv(self, mv: int) -> None:
        limit_mv = int(min(self.info.voltage_max_v, self.info.supply_nominal_v) * 1000.0 + 0.5)
        self.faults &= ~(STICKY_FAULTS | Fault.CLAMPED | Fault.BAD_COMMAND)
        if mv > limit_mv or mv < -limit_mv:
            self.faults |= Fault.CLAMPED
            mv = limit_mv if mv > 0 else -limit_mv
        self.setpoint_mv = mv

    @staticmethod
    def _reply(msg: Message, seq: int) -> bytes:
        return encode_frame(encode_message(msg, seq))

    # -- timer ----------------------------------------------------------------------
    def check_watchdog(self, now_us: int) -> None:
        """Open the armature when the host has been silent longer than the watchdog."""
        # Signed 32-bit difference: wraps of the microsecond clock are harmless.
        silent_us = ((now_us - self.last_host_us + 2**31) % 2**32) - 2**31
        if self.setpoint_mv is not None and silent_us > self.watchdog_ms * 1000:
            self.trip(Fault.WATCHDOG)

    def skip_sample(self) -> None:
        """A sample instant passed without a frame (the counter still advances)."""
        self.counter += 1

    def telemetry(
        self,
        now_us: int,
        encoder_count: int,
        current_a: float,
        terminal_v: float = math.nan,
        supply_v: float = math.nan,
    ) -> bytes:
        """Frame of one telemetry sample (call once per period while streaming)."""
        lsb_v = self.info.voltage_lsb_v
        applied = NOT_MEASURED if self.setpoint_mv is None else _q(self.setpoint_mv / 1000, lsb_v)
        msg = Telemetry(
            self.counter & 0xFFFFFFFF,
            now_us & 0xFFFFFFFF,
            ((encoder_count + 2**31) % 2**32) - 2**31,
            _q(current_a, self.info.current_lsb_a),
            applied,
            _q(terminal_v, lsb_v),
            _q(supply_v, lsb_v),
            self.faults & 0xFF,
        )
        self.counter += 1
        self.faults &= ~Fault.LINK
        return encode_frame(encode_message(msg))
