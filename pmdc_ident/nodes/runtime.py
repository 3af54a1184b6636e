"""How every node of this package runs in its process: one ``main`` for all of them.

rclpy is initialised without its own signal handlers: SIGINT and SIGTERM (Ctrl-C, or
``ros2 launch`` stopping its processes, which may deliver both, and Ctrl-C twice)
only set a flag that the node acts on between callbacks. So no
``KeyboardInterrupt`` can land inside a callback or inside ``destroy_node`` (a
traceback on exit), and every node takes the same way out: stop, wind down (a
recorder drains its queues, the identification node confirms the motor is safe),
close (a driver makes the motor safe), destroy, shut rclpy down.
"""

from __future__ import annotations

import signal
import sys
from collections.abc import Callable
from typing import Any, Protocol

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from pmdc_ident.core.enums import ExitCode, LogLevel
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.process.priority import raise_own_priority

__all__ = ["ManagedNode", "events_executor", "log", "run_node"]


class ManagedNode(Protocol):
    """What :func:`run_node` needs from a node besides :class:`rclpy.node.Node`."""

    finished: bool  # leave the spin loop
    exit_code: int

    def request_stop(self) -> None:
        """A signal arrived (called from the handler: set flags only)."""

    def wind_down(self, spin_once: Callable[[float], None]) -> None:
        """After the loop: spin more while there is something to finish."""

    def close(self) -> list[str]:
        """Release everything (the motor safe first); lines to print on stderr."""


def log(node: Node, level: LogLevel, text: str) -> None:
    """``text`` on the node's logger at ``level``: one call site per severity, as rclpy
    refuses two severities from one line. Anything but a :class:`LogLevel` (a string
    such as ``"eror"``, once logged at info silently) is logged at error, saying so: a
    log line never ends a node (``test/core/test_log_levels.py`` keeps the package's
    levels typed)."""
    logger = node.get_logger()
    if level is LogLevel.ERROR:
        logger.error(text)
    elif level is LogLevel.WARNING:
        logger.warning(text)
    elif level is LogLevel.INFO:
        logger.info(text)
    else:
        logger.error(f"{text} [log level {level!r} is not a LogLevel]")


def events_executor() -> Executor:
    """rclpy's EventsExecutor where it exists (several times less overhead per message
    at 3 kHz of driver samples), else the SingleThreadedExecutor."""
    try:
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    except ImportError:
        return SingleThreadedExecutor()


def run_node(
    name: str,
    build: Callable[[], Any],
    args: list[str] | None = None,
    *,
    executor: Callable[[], Executor] = events_executor,
    realtime: bool = False,
) -> int:
    """Build the node, spin it until it is finished or stopped, close it; exit status.

    ``realtime``: a node of the motor loop, raised to the loop's priority before any
    thread starts where its parent did not choose one (``ros2 run``/``ros2 launch``;
    see :mod:`pmdc_ident.process.priority`). A :class:`PmdcError` while building or
    running is one line and status 2; any other exception one line and status 1.
    """
    if realtime:
        raise_own_priority()
    try:
        rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    except RCLError as exc:  # e.g. a malformed --ros-args rule: one line, no traceback
        text = str(exc).split(", at ")[0]
        print(f"{name}: bad ROS arguments: {text}", file=sys.stderr, flush=True)
        return ExitCode.USER_ERROR
    node: Any = None
    signals: list[int] = []

    def on_signal(signum: int, _frame: Any) -> None:
        signals.append(signum)
        if node is not None:
            node.request_stop()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    status: int = ExitCode.OK
    try:
        node = build()
        if signals:
            node.request_stop()
        ex = executor()
        ex.add_node(node)
        while rclpy.ok() and not node.finished:
            ex.spin_once(timeout_sec=0.05)
        node.wind_down(lambda timeout_s: ex.spin_once(timeout_sec=timeout_s))
        status = node.exit_code
    except PmdcError as exc:
        _say(f"{name}: {exc}")
        status = ExitCode.USER_ERROR
    except ExternalShutdownException:
        pass
    except Exception as exc:  # noqa: BLE001 - one line; the motor is made safe below
        _say(f"{name}: internal error: {exc!r}")
        status = ExitCode.FAILED
    finally:
        if node is not None:
            lines = node.close()  # the motor safe first, whatever happens to the output
            for line in lines:
                _say(f"{name}: {line}")
            node.destroy_node()
        elif signals and status == ExitCode.OK:
            _say(f"{name}: stopped during start-up")
        rclpy.try_shutdown()
        # Done and safe: a late duplicate signal (ros2 launch may send SIGINT and then
        # SIGTERM, Ctrl-C reaches the whole group) must not kill the interpreter while
        # it finalises, which restores the default handlers.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
    return status


def _say(text: str) -> None:
    """One line on stderr; nothing when stderr is gone (ros2 launch killed before us)."""
    try:
        print(text, file=sys.stderr, flush=True)
    except (BrokenPipeError, OSError, ValueError):
        pass
