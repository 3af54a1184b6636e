"""One scheme for the package's ``/diagnostics`` statuses, ROS-free.

Every status is named ``<node's full name without the leading slash>: <what>``
(``left_wheel/driver_node: motor driver``, ``left_wheel/monitor_node: motor drift``;
``driver_node: motor driver`` in the root namespace, the ``diagnostic_updater``
convention), so two motors' statuses never share a name. ``hardware_id`` names the
motor, not the node: by default ``pmdc_motor<namespace>`` (``pmdc_motor/left_wheel``),
which the driver and the monitor of one motor share (both run in its namespace), or
the node's ``hardware_id`` parameter (a serial number, say). :class:`LevelLog` turns a
status's level changes into one log line each.
"""

from __future__ import annotations

from pmdc_ident.core.enums import LogLevel

__all__ = ["LEVEL_NAMES", "LevelLog", "hardware_id", "status_name"]

# diagnostic_msgs/DiagnosticStatus levels
LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}


def status_name(node_fqn: str, what: str) -> str:
    """The status name of ``what`` reported by the node named ``node_fqn``."""
    return f"{node_fqn.lstrip('/')}: {what}"


def hardware_id(namespace: str, given: str = "") -> str:
    """The motor's hardware id: ``given`` when set, else ``pmdc_motor<namespace>``."""
    if given:
        return given
    return "pmdc_motor" + namespace.rstrip("/")


class LevelLog:
    """One line when a status's level changes (starting at OK is not news; another first
    level is said at info). ``causes_logged``: the node logs each cause itself when it
    happens (the driver: a trip, a link lost, the watchdog), so the change is said at
    info, without repeating the cause (one event, one warning or error line)."""

    def __init__(self, what: str, *, causes_logged: bool = False) -> None:
        self.what = what
        self.causes_logged = causes_logged
        self.level: int | None = None

    def update(self, level: int, message: str) -> tuple[LogLevel, str] | None:
        """(log level, line) when ``level`` differs from the last one, else ``None``."""
        old, self.level = self.level, level
        if old == level or (old is None and level == 0):
            return None
        was = "start" if old is None else LEVEL_NAMES.get(old, str(old))
        now = LEVEL_NAMES.get(level, str(level))
        if self.causes_logged:
            return LogLevel.INFO, f"{self.what}: {was} -> {now}"
        # the first status is not a change (a monitor started before its driver is STALE)
        severity = (
            LogLevel.INFO
            if level == 0 or old is None
            else (LogLevel.ERROR if level == 2 else LogLevel.WARNING)
        )
        return severity, f"{self.what}: {was} -> {now}: {message}"
