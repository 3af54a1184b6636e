"""The identification session as a ROS-free state machine.

The identification node feeds every driver sample (driver time, current, speed)
to :meth:`Session.on_sample`, which answers with the command for the next
sample, the segment markers to publish and the progress. The session follows
the *driver's* clock (one plan sample per driver sample), so a slow host never
stretches or shrinks a test. Staircase levels are held until the motor has
really settled (:class:`SteadyStateDetector`: speed drift and current drift over
a trailing window within the measurement noise), with a timeout.

A :class:`SafetyMonitor` checks every sample for over-current, over-speed and
stall (current high while the shaft does not turn); the node adds lost driver
data (:meth:`Session.check_link`), a crashed peer and Ctrl-C through
:meth:`Session.abort`. Every way out of a running session returns the safe
command (armature open, or zero volts, by configuration).

Command convention: ``Command.voltage_v`` is volts, NaN = armature open.

Modules: :mod:`.machine` (:class:`Session`, its commands, steps and progress),
:mod:`.steady_state` (when a staircase level has settled), :mod:`.plan_check` (limits
checked before anything moves); the ``segment`` topic's format is
:mod:`pmdc_ident.core.markers` (the bag reader needs it too), the safety monitor
:mod:`pmdc_ident.core.safety`.
"""

from __future__ import annotations

from pmdc_ident.core.enums import AbortReason
from pmdc_ident.core.markers import Marker, MarkerEvent
from pmdc_ident.core.safety import SafetyConfig, SafetyMonitor
from pmdc_ident.node_logic.session.machine import (
    Command,
    Session,
    SessionProgress,
    SessionState,
    SessionStep,
)
from pmdc_ident.node_logic.session.plan_check import check_plan
from pmdc_ident.node_logic.session.steady_state import SteadyStateConfig, SteadyStateDetector

__all__ = [
    "AbortReason",
    "Command",
    "Marker",
    "MarkerEvent",
    "SafetyConfig",
    "SafetyMonitor",
    "Session",
    "SessionProgress",
    "SessionState",
    "SessionStep",
    "SteadyStateConfig",
    "SteadyStateDetector",
    "check_plan",
]
