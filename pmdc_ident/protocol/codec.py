"""Framing of the pmdc serial protocol: CRC-16/CCITT-FALSE and COBS.

A frame on the wire is ``COBS(payload + crc16_le(payload)) + b"\\x00"``; the
0x00 byte only ever appears as the delimiter, so a receiver re-synchronises on
the next 0x00 after any garbage. See ``docs/serial-protocol.md``.
"""

from __future__ import annotations

from pmdc_ident.protocol.errors import ProtocolError

__all__ = [
    "MAX_ENCODED_BYTES",
    "MAX_PAYLOAD_BYTES",
    "cobs_decode",
    "cobs_encode",
    "crc16_ccitt_false",
    "decode_frame",
    "encode_frame",
]

MAX_PAYLOAD_BYTES = 64  # header + body, without the CRC
# COBS adds at most one byte per 254 plus one; then the delimiter.
MAX_ENCODED_BYTES = MAX_PAYLOAD_BYTES + 2 + 1 + 1


def _crc_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return tuple(table)


_TABLE = _crc_table()


def crc16_ccitt_false(data: bytes | bytearray | memoryview, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final XOR.

    Check value: ``crc16_ccitt_false(b"123456789") == 0x29B1``.
    """
    for b in bytes(data):
        crc = ((crc << 8) & 0xFFFF) ^ _TABLE[(crc >> 8) ^ b]
    return crc


def cobs_encode(data: bytes | bytearray) -> bytes:
    """Consistent Overhead Byte Stuffing: the output holds no 0x00 byte."""
    out = bytearray([0])
    code_idx = 0
    code = 1
    for b in data:
        if b == 0:
            out[code_idx] = code
            code_idx = len(out)
            out.append(0)
            code = 1
        else:
            out.append(b)
            code += 1
            if code == 0xFF:
                out[code_idx] = code
                code_idx = len(out)
                out.append(0)
                code = 1
    out[code_idx] = code
    return bytes(out)


def cobs_decode(data: bytes | bytearray) -> bytes:
    """Inverse of :func:`cobs_encode` (without the delimiter)."""
    out = bytearray()
    i = 0
    n = len(data)
    while i < n:
        code = data[i]
        if code == 0:
            msg = "COBS: zero byte inside a frame"
            raise ProtocolError(msg)
        end = i + code
        if end > n:
            msg = "COBS: frame truncated"
            raise ProtocolError(msg)
        chunk = data[i + 1 : end]
        if 0 in chunk:
            msg = "COBS: zero byte inside a frame"
            raise ProtocolError(msg)
        out += chunk
        i = end
        if code < 0xFF and i < n:
            out.append(0)
    return bytes(out)


def encode_frame(payload: bytes | bytearray) -> bytes:
    """Wire bytes for one payload: COBS(payload + CRC-16 LE) + 0x00."""
    if not payload or len(payload) > MAX_PAYLOAD_BYTES:
        msg = f"payload must be 1..{MAX_PAYLOAD_BYTES} bytes, got {len(payload)}"
        raise ProtocolError(msg)
    crc = crc16_ccitt_false(payload)
    return cobs_encode(bytes(payload) + bytes((crc & 0xFF, crc >> 8))) + b"\x00"


class CrcError(ProtocolError):
    """The frame decoded but its CRC does not match."""


def decode_frame(encoded: bytes | bytearray) -> bytes:
    """Payload of one frame (COBS bytes without the delimiter); checks the CRC.

    Raises :class:`ProtocolError` (or its subclass :class:`CrcError`).
    """
    raw = cobs_decode(encoded)
    if len(raw) < 3:
        msg = f"frame too short ({len(raw)} bytes after COBS)"
        raise ProtocolError(msg)
    if len(raw) > MAX_PAYLOAD_BYTES + 2:
        msg = f"frame too long ({len(raw)} bytes after COBS)"
        raise ProtocolError(msg)
    payload, crc_bytes = raw[:-2], raw[-2:]
    crc = crc_bytes[0] | (crc_bytes[1] << 8)
    if crc16_ccitt_false(payload) != crc:
        msg = "frame CRC mismatch"
        raise CrcError(msg)
    return payload
