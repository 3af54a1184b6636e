"""Errors of the ROS-free core.

Every error a user can cause (bad parameters, malformed data) is a subclass of
:class:`PmdcError` carrying one plain line, so the command line and the nodes can
print it without a traceback.
"""

from __future__ import annotations

__all__ = ["DataError", "ParameterError", "PmdcError"]


class PmdcError(ValueError):
    """Base class: a user-facing error with a one-line message."""


class ParameterError(PmdcError):
    """A motor or effect parameter is missing, non-finite or out of range."""


class DataError(PmdcError):
    """Recorded data are malformed, inconsistent or carry no information."""
