"""A streaming frame parser with a bounded buffer and link statistics."""

from __future__ import annotations

from dataclasses import dataclass

from pmdc_ident.protocol.codec import MAX_ENCODED_BYTES, CrcError, decode_frame
from pmdc_ident.protocol.errors import ProtocolError
from pmdc_ident.protocol.messages import Message, VersionMismatchError, decode_payload

__all__ = ["FrameParser", "ParserStats"]


@dataclass(frozen=True)
class ParserStats:
    frames_ok: int = 0
    crc_errors: int = 0
    framing_errors: int = 0  # bad COBS, truncated, too short
    oversize_frames: int = 0  # longer than any valid frame: dropped while reading
    bad_messages: int = 0  # valid CRC, unknown type or wrong length
    bytes_in: int = 0

    @property
    def errors(self) -> int:
        return self.crc_errors + self.framing_errors + self.oversize_frames + self.bad_messages


class FrameParser:
    """Feed it bytes in any chunking; get back ``(seq, message)`` pairs.

    The buffer never holds more than ``MAX_ENCODED_BYTES``: a longer run without
    a delimiter is dropped and counted, and parsing resumes at the next 0x00.
    Errors are counted, never raised, except a :class:`VersionMismatchError`, which
    is returned in place of a message so the caller can report it.
    """

    def __init__(self) -> None:
        self._buf = bytearray()
        self._overflow = False
        self._frames_ok = 0
        self._crc = 0
        self._framing = 0
        self._oversize = 0
        self._bad = 0
        self._bytes = 0
        self.last_error = ""

    def reset(self) -> None:
        """Forget a partial frame (after reopening a port); statistics are kept."""
        self._buf.clear()
        self._overflow = False

    @property
    def buffered_bytes(self) -> int:
        return len(self._buf)

    @property
    def stats(self) -> ParserStats:
        return ParserStats(
            self._frames_ok, self._crc, self._framing, self._oversize, self._bad, self._bytes
        )

    def feed(self, data: bytes | bytearray) -> list[tuple[int, Message | VersionMismatchError]]:
        """Decoded ``(seq, message)`` pairs of the complete frames in ``data``."""
        out: list[tuple[int, Message | VersionMismatchError]] = []
        for payload in self.feed_payloads(data):
            try:
                item = decode_payload(payload)
            except VersionMismatchError as exc:
                out.append((payload[1], exc))
                continue
            except ProtocolError as exc:
                self._frames_ok -= 1
                self._bad += 1
                self.last_error = str(exc)
                continue
            out.append(item)
        return out

    def feed_payloads(self, data: bytes | bytearray) -> list[bytes]:
        """CRC-checked payloads of the complete frames in ``data``, not decoded."""
        out: list[bytes] = []
        self._bytes += len(data)
        start = 0
        n = len(data)
        while start < n:
            end = data.find(0, start)
            chunk = data[start:] if end < 0 else data[start:end]
            if not self._overflow:
                if len(self._buf) + len(chunk) > MAX_ENCODED_BYTES:
                    self._overflow = True
                    self._oversize += 1
                    self.last_error = "frame longer than any valid frame (garbage on the line?)"
                    self._buf.clear()
                else:
                    self._buf += chunk
            if end < 0:
                break
            if self._overflow:
                self._overflow = False
            elif self._buf:
                payload = self._check(bytes(self._buf))
                if payload is not None:
                    out.append(payload)
            self._buf.clear()
            start = end + 1
        return out

    def _check(self, encoded: bytes) -> bytes | None:
        try:
            payload = decode_frame(encoded)
        except CrcError as exc:
            self._crc += 1
            self.last_error = str(exc)
            return None
        except ProtocolError as exc:
            self._framing += 1
            self.last_error = str(exc)
            return None
        if len(payload) < 2:
            self._framing += 1
            self.last_error = "frame without a header"
            return None
        self._frames_ok += 1
        return payload
