"""Shared vocabulary of the driver, the protocol, the backends and the session.

One place for the enums several layers use, so that none of them has to import a
layer above it: the serial protocol (:mod:`pmdc_ident.protocol`) and every backend
(:mod:`pmdc_ident.backends`) carry :class:`Fault` bits, the driver and the session
make the motor safe the :class:`SafeMode` way, a session that stops early says
why with an :class:`AbortReason`, the identification node publishes its state as a
:class:`SessionStatus`, and every program of the package (``pmdc-ident``, the nodes,
the bring-up, the demo) ends with an :class:`ExitCode`. A line the core or a backend
hands to a node's logger carries its :class:`LogLevel`.
"""

from __future__ import annotations

import enum

__all__ = [
    "AbortReason",
    "ExitCode",
    "Fault",
    "LogLevel",
    "ParameterNote",
    "SafeMode",
    "SessionStatus",
]


class SafeMode(enum.Enum):
    """What 'safe' means for this rig: open the armature, or hold zero volts (brake)."""

    OPEN = "open"
    ZERO = "zero"


class Fault(enum.IntFlag):
    """Fault flags carried by telemetry.

    The values are the wire format of serial protocol v1 and equal the firmware's
    ``PMDC_FAULT_*`` (``firmware/protocol/pmdc_protocol.h``; a test compares them).
    """

    NONE = 0
    OVER_CURRENT = 1
    OVER_SPEED = 2
    WATCHDOG = 4  # no command within the watchdog time: armature opened
    SUPPLY = 8  # supply voltage out of range
    CLAMPED = 16  # last command exceeded the voltage limit and was clamped
    BAD_COMMAND = 32  # NaN/inf command refused
    LINK = 64  # host link problem (checksum errors, lost frames)


class AbortReason(enum.Enum):
    """Why a session stopped early (the value is what the ``status`` topic carries),
    and which limit a :class:`~pmdc_ident.core.safety.SafetyMonitor` tripped."""

    OVER_CURRENT = "over_current"
    OVER_SPEED = "over_speed"
    STALL = "stall"
    LOST_DRIVER_DATA = "lost_driver_data"
    PEER_CRASHED = "peer_crashed"
    INTERRUPTED = "interrupted"
    DRIVER_FAULT = "driver_fault"
    OUT_OF_TRAVEL = "out_of_travel"  # the measured position left the joint's travel range


class SessionStatus(enum.Enum):
    """The ``state`` of the identification node's ``status`` topic: its one vocabulary.

    The values are the strings of the topic's JSON, a stable interface
    (``docs/reference.md``): ``idle``, ``preparing``, ``running`` and ``identifying``
    follow the controller's phase (``Phase.status``); the others say how a request or
    a session ended.
    """

    IDLE = "idle"
    PREPARING = "preparing"  # waiting for the driver, its limits and the recorder
    RUNNING = "running"
    IDENTIFYING = "identifying"
    DONE = "done"  # identified: parameters published and written
    FAILED = "failed"  # the identification of the session failed
    REFUSED = "refused"  # a request or a setting refused before anything moved
    STOPPED = "stopped"  # stopped by a signal
    ABORTED = "aborted"  # a tripped limit or a lost peer ended the session


class ParameterNote(enum.Enum):
    """What an estimated parameter's ``reason`` says, by code: the table and the checks
    match these, never the words (``ParameterEstimate.notes``; the JSON keeps the words).
    """

    FIXED = "fixed"  # held at the user's value
    ASSUMED = "assumed"  # set by an assumption (the Kt = Ke closure), not measured
    WEAKLY_IDENTIFIABLE = "weakly"  # relative standard error 10-50 %
    FAST_ELECTRICAL = "L/R"  # L/R at or below the sample period: how L was still pinned
    ONE_TERM = "one term"  # Coulomb friction and a load torque, one direction only
    GATE_EXPECTED = "gate expected"  # the gate expected more doubt than the fit's bound


class ExitCode(enum.IntEnum):
    """The exit statuses of every program of the package (``docs/reference.md`` §4).

    An ``IntEnum``: a status is returned and passed to ``sys.exit`` as it is, and a
    process's return code compares equal to its member.
    """

    OK = 0
    FAILED = 1  # a bug of ours (one line), or a job that did not keep its promise
    USER_ERROR = 2  # one line: bad option, input or parameter; refused before anything moved
    ABORTED = 3  # a session stopped by an abort (a tripped limit, a lost peer)
    INTERRUPTED = 130  # Ctrl-C or a signal cut the job short (128 + SIGINT)


class LogLevel(enum.Enum):
    """The severity of a line the ROS-free code hands to a node's logger (the session
    controller's ports, the driver, a status's level change, the worker's notes): the
    node calls rclpy's ``info``, ``warning`` or ``error`` for it
    (:func:`pmdc_ident.nodes.runtime.log`). A plain ``Enum``: a misspelt string is an
    error where it is written, not a line silently logged at info."""

    INFO = "info"
    WARNING = "warning"
    ERROR = "error"
