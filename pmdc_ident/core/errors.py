"""Errors of the ROS-free core, and the caller's words for its options.

Every error a user can cause (bad parameters, malformed data) is a subclass of
:class:`PmdcError` carrying one plain line, so the command line and the nodes can
print it without a traceback.

The same core runs behind the command line, where the user types ``--fix``, and
behind the nodes, where the user sets the ``fix`` ROS parameter. So the core never
spells an option itself: an error about one is an :class:`OptionError` (which option,
by its neutral key such as ``fix`` or ``speed_unit``; the value given; why), and a hint
that names an option asks :func:`option_name` for it. Each front end states its words
with :func:`wording` (the command line's table is ``pmdc_ident.app.CLI_NAMES``, the
identification node's ``pmdc_ident.process.identify_call.NODE_NAMES``); where none did
(a library call), an option is named as the command line spells it, ``--`` and the key
with dashes.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar

__all__ = [
    "DataError",
    "DataOptionError",
    "OptionError",
    "ParameterError",
    "PmdcError",
    "SignalRangeError",
    "option_name",
    "wording",
]


class PmdcError(ValueError):
    """Base class: a user-facing error with a one-line message."""


class ParameterError(PmdcError):
    """A motor or effect parameter is missing, non-finite or out of range."""


class DataError(PmdcError):
    """Recorded data are malformed, inconsistent or carry no information."""


class SignalRangeError(DataError):
    """A sample beyond any motor test (:data:`pmdc_ident.core.data.SIGNAL_LIMITS`): which
    ``signal``, its ``value`` and ``unit`` (SI), so a caller can say which unit it was
    probably in without reading the message."""

    def __init__(self, message: str, *, signal: str, value: float, unit: str) -> None:
        super().__init__(message)
        self.signal = signal
        self.value = value
        self.unit = unit

    def __reduce__(self) -> tuple[object, ...]:  # to another process as what it is
        return (_signal_range_error, (str(self), self.signal, self.value, self.unit))

    def prefixed(self, prefix: str) -> SignalRangeError:
        """The same error with ``prefix`` before its message (where it was read)."""
        return SignalRangeError(
            f"{prefix}{self}", signal=self.signal, value=self.value, unit=self.unit
        )


def _signal_range_error(message: str, signal: str, value: float, unit: str) -> SignalRangeError:
    return SignalRangeError(message, signal=signal, value=value, unit=unit)


# -- the caller's words ---------------------------------------------------------------
_WORDING: ContextVar[Mapping[str, str] | None] = ContextVar("pmdc_ident_wording", default=None)


def option_name(key: str, names: Mapping[str, str] | None = None) -> str:
    """Option ``key`` (``fix``, ``speed_unit``) in the words of ``names``, else of the
    front end running (:func:`wording`), else ``--`` and the key with dashes."""
    table = _WORDING.get() if names is None else names
    if table is not None and key in table:
        return table[key]
    return "--" + key.replace("_", "-")


@contextmanager
def wording(names: Mapping[str, str]) -> Iterator[None]:
    """Within the block, options are named by ``names`` (neutral key -> the caller's
    words: ``{"fix": "--fix"}`` on the command line, ``{"fix": "parameter fix"}`` in the
    node)."""
    token = _WORDING.set(names)
    try:
        yield
    finally:
        _WORDING.reset(token)


class OptionError(ParameterError):
    """A value given for one option that the core refuses: ``key`` (the option's neutral
    name), ``value`` (as given) and ``reason`` (the rest of the line). The line names the
    option in the caller's words, looked up when it is printed (:func:`option_name`), or
    in given words with :meth:`render`. ``sep`` joins the name and the reason."""

    def __init__(self, key: str, value: object, reason: str, *, sep: str = " ") -> None:
        super().__init__(reason)
        self.key = key
        self.value = value
        self.reason = reason
        self.sep = sep

    def render(self, names: Mapping[str, str] | None = None) -> str:
        """The line, the option named by ``names`` (default: the front end's words)."""
        return f"{option_name(self.key, names)}{self.sep}{self.reason}"

    def __str__(self) -> str:
        return self.render()

    def __reduce__(self) -> tuple[object, ...]:  # to another process as what it is
        return (type(self), (self.key, self.value, self.reason), {"sep": self.sep})


class DataOptionError(OptionError, DataError):
    """An :class:`OptionError` about how to read the data (columns, units)."""
