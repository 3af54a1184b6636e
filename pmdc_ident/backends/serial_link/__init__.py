"""The parts of :class:`~pmdc_ident.backends.serial_board.SerialBackend`, one concept each.

- :mod:`.port`: the transport, one serial port (open, numbered frames out, bytes in);
- :mod:`.handshake`: HELLO, HELLO_ACK, START_STREAM, ACK: the stream's negotiation;
- :mod:`.decoder`: telemetry frames to samples on the board's own time axis;
- :mod:`.delivery`: samples from the reader thread to ``poll()``, with the host-stall rule;
- :mod:`.reconnect`: the link's state machine (streaming, lost and retrying, failed);
- :mod:`.stats`: link statistics, the parser's error watch and the keep-alive round trip;
- :mod:`.errors`: the link-lost signal and the names of the wire's codes in messages.
"""

from __future__ import annotations

from pmdc_ident.backends.serial_link.reconnect import LinkState
from pmdc_ident.backends.serial_link.stats import LinkStats

__all__ = ["LinkState", "LinkStats"]
