"""Link statistics for ``/diagnostics``: counters, the parser's error watch, ping RTT."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from pmdc_ident.backends.serial_link.reconnect import LinkState
from pmdc_ident.protocol import FrameParser

__all__ = ["LinkCounters", "LinkStats", "ParserWatch", "PingClock"]

PINGS_REMEMBERED = 16


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


@dataclass
class LinkCounters:
    """What the board and the link did since the backend was made."""

    board_errors: int = 0  # ERROR replies
    board_resets: int = 0  # BOOT frames and lost sessions (NOT_READY)
    reconnects: int = 0
    last_error: str = ""


class ParserWatch:
    """Notices new link errors in the parser's counts and logs them, once a second."""

    def __init__(self, parser: FrameParser, port_name: str, log: Callable[[str], None]) -> None:
        self._parser = parser
        self._port = port_name
        self._log = log
        self._seen_errors = 0
        self._last_log = 0.0

    def new_errors(self, now: float) -> str | None:
        """The parser's last error when errors were counted since the last call."""
        errors = self._parser.stats.errors
        if errors == self._seen_errors:
            return None
        if now - self._last_log >= 1.0:
            s = self._parser.stats
            self._log(
                f"serial board {self._port}: link errors (crc {s.crc_errors}, framing "
                f"{s.framing_errors}, oversize {s.oversize_frames}, bad {s.bad_messages} "
                f"so far; last: {self._parser.last_error})"
            )
            self._last_log = now
        self._seen_errors = errors
        return self._parser.last_error


class PingClock:
    """Keep-alive tokens sent, and the round trip of the last one answered."""

    def __init__(self) -> None:
        self.rtt_s = math.nan
        self._lock = threading.Lock()  # the reader thread pops answered pings
        self._sent: dict[int, float] = {}

    def token(self) -> int:
        """A new token, remembered as sent now."""
        token = int(time.monotonic_ns() // 1000) & 0xFFFFFFFF
        with self._lock:
            self._sent[token] = time.monotonic()
            if len(self._sent) > PINGS_REMEMBERED:
                self._sent.pop(next(iter(self._sent)))
        return token

    def answered(self, token: int) -> None:
        with self._lock:
            sent = self._sent.pop(token, None)
        if sent is not None:
            self.rtt_s = time.monotonic() - sent
