"""Messages of the pmdc serial protocol, version 1 (``docs/serial-protocol.md``).

A payload is ``type (u8) | seq (u8) | body``; bodies are little-endian fixed
structs. Host -> board types are below 0x80, board -> host types 0x80 and up.
Voltages and currents in telemetry are int16 counts of the LSBs the board
announces in :class:`HelloAck`; ``NOT_MEASURED`` (-32768) marks a quantity the
board does not measure, and in ``applied_v`` an open armature.
"""

from __future__ import annotations

import enum
import struct
from dataclasses import dataclass, fields
from typing import ClassVar

from pmdc_ident.protocol.codec import decode_frame, encode_frame
from pmdc_ident.protocol.errors import ProtocolError

__all__ = [
    "BAUD_BUDGET",
    "BITS_PER_BYTE",
    "MESSAGE_TYPES",
    "NOT_MEASURED",
    "PROTOCOL_VERSION",
    "TELEMETRY_WIRE_BYTES",
    "Ack",
    "Boot",
    "Capability",
    "ErrorCode",
    "ErrorReply",
    "Hello",
    "HelloAck",
    "Message",
    "MsgType",
    "OpenArmature",
    "Ping",
    "Pong",
    "SetDuty",
    "SetVoltage",
    "StartStream",
    "StopStream",
    "Telemetry",
    "decode_payload",
    "encode_message",
    "frame_message",
    "min_period_us",
    "parse_frame",
]

PROTOCOL_VERSION = 1
NOT_MEASURED = -32768
BITS_PER_BYTE = 10  # 8N1: start + 8 data + stop
BAUD_BUDGET = 0.9  # telemetry may use at most 90 % of the board -> host line


class MsgType(enum.IntEnum):
    HELLO = 0x01
    START_STREAM = 0x02
    STOP_STREAM = 0x03
    SET_VOLTAGE = 0x04
    SET_DUTY = 0x05
    OPEN_ARMATURE = 0x06
    PING = 0x07
    ACK = 0x80
    HELLO_ACK = 0x81
    TELEMETRY = 0x82
    PONG = 0x87
    ERROR = 0x8E
    BOOT = 0x8F


class ErrorCode(enum.IntEnum):
    UNKNOWN_TYPE = 1
    BAD_LENGTH = 2
    VERSION = 3  # detail: the board's protocol version
    RATE_TOO_HIGH = 4  # detail: the shortest period the board accepts, us
    NOT_READY = 5  # command before a successful HELLO
    BAD_VALUE = 6  # e.g. duty outside -32767..32767


class Capability(enum.IntFlag):
    NONE = 0
    TERMINAL_VOLTAGE = 1  # board measures the armature terminal voltage
    SUPPLY_VOLTAGE = 2  # board measures the bridge supply voltage
    OPEN_ARMATURE = 4  # bridge can disconnect the winding (coast)
    CURRENT = 8  # board measures armature current


@dataclass(frozen=True)
class Message:
    TYPE: ClassVar[MsgType]
    FORMAT: ClassVar[str] = ""

    def body(self) -> bytes:
        return struct.pack("<" + self.FORMAT, *self._values())

    def _values(self) -> tuple[int | float, ...]:
        return tuple(getattr(self, f.name) for f in fields(self))


@dataclass(frozen=True)
class Hello(Message):
    TYPE = MsgType.HELLO
    FORMAT = "B"
    host_version: int = PROTOCOL_VERSION


@dataclass(frozen=True)
class StartStream(Message):
    TYPE = MsgType.START_STREAM
    FORMAT = "IH"
    period_us: int
    watchdog_ms: int


@dataclass(frozen=True)
class StopStream(Message):
    TYPE = MsgType.STOP_STREAM


@dataclass(frozen=True)
class SetVoltage(Message):
    TYPE = MsgType.SET_VOLTAGE
    FORMAT = "i"
    millivolts: int


@dataclass(frozen=True)
class SetDuty(Message):
    TYPE = MsgType.SET_DUTY
    FORMAT = "h"
    duty_q15: int  # -32767..32767 = -100 %..100 % of the supply


@dataclass(frozen=True)
class OpenArmature(Message):
    TYPE = MsgType.OPEN_ARMATURE


@dataclass(frozen=True)
class Ping(Message):
    TYPE = MsgType.PING
    FORMAT = "I"
    token: int


@dataclass(frozen=True)
class Ack(Message):
    TYPE = MsgType.ACK
    FORMAT = "B"
    acked_type: int


@dataclass(frozen=True)
class HelloAck(Message):
    """The board's description. Its first body byte (the version) is frozen forever."""

    TYPE = MsgType.HELLO_ACK
    FORMAT = "BBHIIffff"
    protocol_version: int
    capabilities: int
    firmware_version: int
    min_period_us: int  # shortest telemetry period it accepts (timer and baud)
    counts_per_rev: int
    current_lsb_a: float
    voltage_lsb_v: float
    supply_nominal_v: float
    voltage_max_v: float


@dataclass(frozen=True)
class Telemetry(Message):
    TYPE = MsgType.TELEMETRY
    FORMAT = "IIihhhhB"
    counter: int  # sample index since START_STREAM
    time_us: int  # board clock at the sample (wraps at 2**32)
    encoder_count: int  # quadrature counts (wraps at 2**32)
    current: int  # current_lsb_a counts
    applied_v: int  # voltage_lsb_v counts held over this sample; NOT_MEASURED = open
    terminal_v: int  # voltage_lsb_v counts; NOT_MEASURED when not measured
    supply_v: int  # voltage_lsb_v counts; NOT_MEASURED when not measured
    faults: int  # pmdc_ident.core.enums.Fault bits


@dataclass(frozen=True)
class Pong(Message):
    TYPE = MsgType.PONG
    FORMAT = "II"
    token: int
    time_us: int


@dataclass(frozen=True)
class ErrorReply(Message):
    TYPE = MsgType.ERROR
    FORMAT = "BBI"
    refused_type: int
    code: int
    detail: int


@dataclass(frozen=True)
class Boot(Message):
    """Sent unsolicited after power-up or reset. Its first body byte is frozen forever."""

    TYPE = MsgType.BOOT
    FORMAT = "BH"
    protocol_version: int
    firmware_version: int


MESSAGE_TYPES: dict[int, type[Message]] = {
    cls.TYPE: cls
    for cls in (
        Hello,
        StartStream,
        StopStream,
        SetVoltage,
        SetDuty,
        OpenArmature,
        Ping,
        Ack,
        HelloAck,
        Telemetry,
        Pong,
        ErrorReply,
        Boot,
    )
}
_SIZES = {t: struct.calcsize("<" + cls.FORMAT) for t, cls in MESSAGE_TYPES.items()}


def encode_message(msg: Message, seq: int = 0) -> bytes:
    """Payload bytes (type, seq, body) of a message; raises ProtocolError on bad fields."""
    try:
        body = msg.body()
    except struct.error as exc:
        msg_text = f"{type(msg).__name__}: field out of range ({exc})"
        raise ProtocolError(msg_text) from None
    return bytes((int(msg.TYPE), seq & 0xFF)) + body


def frame_message(msg: Message, seq: int = 0) -> bytes:
    """Wire bytes of a message: COBS frame with CRC and delimiter."""
    return encode_frame(encode_message(msg, seq))


def decode_payload(payload: bytes | bytearray) -> tuple[int, Message]:
    """``(seq, message)`` of a payload; ProtocolError for unknown types or bad lengths."""
    if len(payload) < 2:
        msg = f"payload too short ({len(payload)} bytes)"
        raise ProtocolError(msg)
    kind, seq = payload[0], payload[1]
    cls = MESSAGE_TYPES.get(kind)
    if cls is None:
        msg = f"unknown message type 0x{kind:02x}"
        raise ProtocolError(msg)
    body = bytes(payload[2:])
    if len(body) != _SIZES[kind]:
        # HELLO_ACK and BOOT of another version: the version byte still decodes.
        if kind in (MsgType.HELLO_ACK, MsgType.BOOT) and body and body[0] != PROTOCOL_VERSION:
            msg = f"board speaks protocol v{body[0]}; this host speaks v{PROTOCOL_VERSION}"
            raise VersionMismatchError(msg, body[0])
        msg = f"{cls.__name__}: body of {len(body)} bytes, expected {_SIZES[kind]}"
        raise ProtocolError(msg)
    values = struct.unpack("<" + cls.FORMAT, body)
    return seq, cls(*values)


class VersionMismatchError(ProtocolError):
    """The peer speaks another protocol version."""

    def __init__(self, message: str, version: int) -> None:
        super().__init__(message)
        self.version = version


def parse_frame(encoded: bytes | bytearray) -> tuple[int, Message]:
    """Decode one frame (COBS bytes without the delimiter) to ``(seq, message)``."""
    return decode_payload(decode_frame(encoded))


def min_period_us(baud: int, frame_bytes: int | None = None) -> int:
    """Shortest telemetry period that fits ``BAUD_BUDGET`` of a ``baud`` 8N1 line."""
    nbytes = TELEMETRY_WIRE_BYTES if frame_bytes is None else frame_bytes
    return -(-(nbytes * BITS_PER_BYTE * 1_000_000) // int(baud * BAUD_BUDGET))


# 2 header + 21 body + 2 CRC + 1 COBS + 1 delimiter
TELEMETRY_WIRE_BYTES = len(frame_message(Telemetry(0, 0, 0, 0, 0, 0, 0, 0)))
