"""The link's state machine: streaming, lost (and retrying), failed, closed.

A lost link is retried every ``interval_s`` in the background; a fatal loss (protocol
version mismatch, refused rate, another program's terminal) or a backend told not to
reconnect fails for good. A loss is reported once, by the next ``poll()``: when the
link was streaming, or when the loss is fatal.
"""

from __future__ import annotations

import enum

__all__ = ["LinkState", "Reconnection"]


class LinkState(enum.Enum):
    CLOSED = "closed"
    STREAMING = "streaming"
    LOST = "lost"  # reconnecting in the background
    FAILED = "failed"  # will not reconnect (version mismatch, refused rate, closed)


class Reconnection:
    """Where the link stands, when it was lost and when to try again."""

    def __init__(self, *, enabled: bool, interval_s: float) -> None:
        self.state = LinkState.CLOSED
        self.lost_at = 0.0  # time.monotonic() of the last loss (0: never lost)
        self._enabled = enabled
        self._interval_s = interval_s
        self._next_attempt = 0.0

    def streaming(self) -> None:
        self.state = LinkState.STREAMING

    def failed(self) -> None:
        self.state = LinkState.FAILED

    def closed(self) -> None:
        self.state = LinkState.CLOSED

    def lose(self, message: str, now: float, *, fatal: bool) -> str | None:
        """The link failed at ``now``: the line to report to the user, or ``None`` when
        the loss was already reported (a reconnection attempt that failed too)."""
        was = self.state
        self.lost_at = now
        if fatal or not self._enabled:
            self.state = LinkState.FAILED
            tail = "; motor commanded safe; not reconnecting"
        else:
            self.state = LinkState.LOST
            tail = "; motor commanded safe; reconnecting"
            self._next_attempt = now + self._interval_s
        if was is LinkState.STREAMING or fatal:
            return message + tail
        return None

    def wait_s(self, now: float) -> float:
        """Seconds until the next attempt; 0: attempt now (the one after is scheduled)."""
        if now < self._next_attempt:
            return self._next_attempt - now
        self._next_attempt = now + self._interval_s
        return 0.0
