"""Errors of the serial protocol layer."""

from __future__ import annotations

from pmdc_ident.core.errors import PmdcError

__all__ = ["ProtocolError"]


class ProtocolError(PmdcError):
    """A frame or message that does not follow the protocol (one plain line)."""
