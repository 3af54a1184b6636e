"""The pmdc serial protocol (ROS-free): COBS framing, CRC-16, messages, parser.

See ``docs/serial-protocol.md`` for the wire format.
"""

from __future__ import annotations

from pmdc_ident.protocol.codec import (
    CrcError,
    cobs_decode,
    cobs_encode,
    crc16_ccitt_false,
    decode_frame,
    encode_frame,
)
from pmdc_ident.protocol.errors import ProtocolError
from pmdc_ident.protocol.messages import (
    PROTOCOL_VERSION,
    TELEMETRY_WIRE_BYTES,
    Ack,
    Boot,
    Capability,
    ErrorCode,
    ErrorReply,
    Hello,
    HelloAck,
    Message,
    MsgType,
    OpenArmature,
    Ping,
    Pong,
    SetDuty,
    SetVoltage,
    StartStream,
    StopStream,
    Telemetry,
    VersionMismatchError,
    decode_payload,
    encode_message,
    frame_message,
    min_period_us,
    parse_frame,
)
from pmdc_ident.protocol.parser import FrameParser, ParserStats

__all__ = [
    "PROTOCOL_VERSION",
    "TELEMETRY_WIRE_BYTES",
    "Ack",
    "Boot",
    "Capability",
    "CrcError",
    "ErrorCode",
    "ErrorReply",
    "FrameParser",
    "Hello",
    "HelloAck",
    "Message",
    "MsgType",
    "OpenArmature",
    "ParserStats",
    "Ping",
    "Pong",
    "ProtocolError",
    "SetDuty",
    "SetVoltage",
    "StartStream",
    "StopStream",
    "Telemetry",
    "VersionMismatchError",
    "cobs_decode",
    "cobs_encode",
    "crc16_ccitt_false",
    "decode_frame",
    "decode_payload",
    "encode_frame",
    "encode_message",
    "frame_message",
    "min_period_us",
    "parse_frame",
]
