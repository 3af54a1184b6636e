"""The stream's negotiation: HELLO, HELLO_ACK, START_STREAM, ACK.

The host says HELLO (again every 250 ms until answered); the board answers with its
HELLO_ACK (protocol version, limits, scales, fastest period at this baud); the host asks
for the stream at its period and board watchdog and the board ACKs it. A protocol
version mismatch or a refused rate is fatal: reconnecting cannot mend it.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from pmdc_ident.backends.base import BackendError
from pmdc_ident.backends.serial_link.errors import LinkLostError, error_name
from pmdc_ident.backends.serial_link.port import SerialPort
from pmdc_ident.protocol import (
    PROTOCOL_VERSION,
    Ack,
    ErrorCode,
    ErrorReply,
    FrameParser,
    Hello,
    HelloAck,
    Message,
    StartStream,
    VersionMismatchError,
)
from pmdc_ident.protocol import Telemetry as WireTelemetry

__all__ = ["StreamRequest", "negotiate", "rate_text", "version_text"]

HELLO_EVERY_S = 0.25


@dataclass(frozen=True)
class StreamRequest:
    """What the host asks of the board: its sample period and watchdog."""

    dt_s: float
    board_watchdog_ms: int
    timeout_s: float  # the whole handshake's

    @property
    def period_us(self) -> int:
        return int(round(self.dt_s * 1e6))


def negotiate(
    port: SerialPort, parser: FrameParser, request: StreamRequest, stop: threading.Event
) -> tuple[HelloAck, list[WireTelemetry]]:
    """Handshake on an open port: the board's HELLO_ACK and the telemetry that arrived
    after its ACK in the same read (the stream's first samples). Raises LinkLostError."""
    parser.reset()
    port.discard_input()
    deadline = time.monotonic() + request.timeout_s
    info: HelloAck | None = None
    start_seq = -1
    next_hello = 0.0
    while True:
        now = time.monotonic()
        if stop.is_set():
            msg = f"serial board on {port.name}: closed during the handshake"
            raise LinkLostError(msg)
        if now > deadline:
            what = "HELLO" if info is None else "START_STREAM"
            msg = (
                f"no answer to {what} from a pmdc board on {port.name} at {port.baud} baud "
                f"within {request.timeout_s:g} s (wrong port or baud, or no firmware?)"
            )
            raise LinkLostError(msg)
        if info is None and now >= next_hello:
            _send(port, Hello(PROTOCOL_VERSION))
            next_hello = now + HELLO_EVERY_S
        acked: list[WireTelemetry] | None = None
        for seq, item in parser.feed(port.read()):
            if isinstance(item, VersionMismatchError):
                raise LinkLostError(version_text(port.name, item.version), fatal=True)
            if isinstance(item, HelloAck) and info is None:
                info = _checked(port, request, item)
                start_seq = _send(port, StartStream(request.period_us, request.board_watchdog_ms))
            elif isinstance(item, ErrorReply) and seq == start_seq:
                if item.code == ErrorCode.RATE_TOO_HIGH:
                    raise LinkLostError(rate_text(port, request, item.detail), fatal=True)
                msg = f"board refused START_STREAM ({error_name(item.code)})"
                raise LinkLostError(msg)
            elif isinstance(item, Ack) and seq == start_seq and acked is None:
                acked = []
            elif acked is not None and isinstance(item, WireTelemetry):
                acked.append(item)
        if acked is not None:
            assert info is not None
            return info, acked


def _checked(port: SerialPort, request: StreamRequest, info: HelloAck) -> HelloAck:
    """The board's HELLO_ACK, if it speaks this protocol and streams this fast."""
    if info.protocol_version != PROTOCOL_VERSION:
        raise LinkLostError(version_text(port.name, info.protocol_version), fatal=True)
    if request.period_us < info.min_period_us:
        raise LinkLostError(rate_text(port, request, info.min_period_us), fatal=True)
    return info


def _send(port: SerialPort, msg: Message) -> int:
    try:
        return port.send(msg)
    except BackendError as exc:
        raise LinkLostError(str(exc)) from None


def version_text(port_name: str, version: int) -> str:
    return (
        f"board on {port_name} speaks pmdc protocol v{version}; this host speaks "
        f"v{PROTOCOL_VERSION}: flash matching firmware or update pmdc_ident"
    )


def rate_text(port: SerialPort, request: StreamRequest, min_us: int) -> str:
    dt_s = request.dt_s
    return (
        f"a {1.0 / dt_s:g} Hz stream (dt_s = {dt_s * 1e3:g} ms) is faster than "
        f"the board streams at {port.baud} baud (at most {1e6 / min_us:.0f} Hz, period >= "
        f"{min_us / 1e3:g} ms): raise the baud or lower the rate"
    )
