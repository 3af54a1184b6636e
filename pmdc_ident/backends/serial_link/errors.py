"""The link-lost signal of the serial backend's parts, and the wire's codes in words."""

from __future__ import annotations

import os

from pmdc_ident.protocol import ErrorCode, MsgType

__all__ = ["LinkLostError", "error_name", "reason", "type_name"]


class LinkLostError(Exception):
    """Internal: the link failed; message and whether reconnecting makes sense."""

    def __init__(self, message: str, fatal: bool = False) -> None:
        super().__init__(message)
        self.fatal = fatal


def reason(exc: BaseException) -> str:
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


def error_name(code: int) -> str:
    """A board's ERROR code by name (``RATE_TOO_HIGH``), or its number."""
    try:
        return ErrorCode(code).name
    except ValueError:
        return f"error {code}"


def type_name(kind: int) -> str:
    """A message type by name (``SET_VOLTAGE``), or its number."""
    try:
        return MsgType(kind).name
    except ValueError:
        return f"type 0x{kind:02x}"
