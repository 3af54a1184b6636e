"""What ``launch/session.launch.py`` and ``launch/driver.launch.py`` decide.

The decisions are plain Python (tested without ``launch``): which launch argument
reaches which node parameter (:data:`SESSION_ARGUMENTS`, :data:`DRIVER_ARGUMENTS`),
the parameter list of each node (:func:`node_parameters`), and, for a launch holding
one or more sessions, what the launch does when a process ends
(:class:`SessionRegistry`). :func:`session_actions` wires them to the ``launch`` API
(imported inside it: ``launch`` comes with a ROS installation, not with this package).

Parameters reach a node in this order, each over the one before: the node's file in
``share/pmdc_ident/config/`` (every default, generated from the node's table), the
launch's ``params_file`` (one file for every node of the launch, keyed ``/**`` or by
node name), and the launch arguments actually given (an argument left at its ``''``
default does not override anything). A session ends on its own: when its
identification node exits, that session's recorder and driver get SIGINT (the driver
then holds 0 V until no node commands it, and opens); nothing else in the launch is
stopped, so two sessions in one launch (two wheels, two namespaces) both run to their
end. When every session of the launch is over and one of them did not complete (a
process ended with a non-zero status: 2 refused, 3 aborted, 130 interrupted, ...), the
launch reports it in one error line and ``ros2 launch`` exits with status 1.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from pmdc_ident.core.enums import ExitCode
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.process.parameter_tables import DRIVER, IDENTIFICATION, RECORDER, ParameterTable

__all__ = [
    "DRIVER_ARGUMENTS",
    "LAUNCH_DEFAULTS",
    "REGISTRY_KEY",
    "SESSION_ARGUMENTS",
    "LaunchArgument",
    "SessionRegistry",
    "exit_meaning",
    "node_parameters",
    "overrides",
    "session_actions",
]


@dataclass(frozen=True)
class LaunchArgument:
    """A launch argument and the node parameters it sets (``''``: leave them)."""

    name: str
    targets: tuple[tuple[str, str], ...]  # (node name, parameter name)
    description: str


def _arg(name: str, *targets: tuple[ParameterTable, str]) -> LaunchArgument:
    table, param = targets[0]
    p = table[param]
    default = str(p.default).lower() if isinstance(p.default, bool) else str(p.default)
    where = ", ".join(f"{t.node} {q}" for t, q in targets)
    desc = f"{p.description} [{where}; '' = the parameters file's, {default or repr('')}]"
    return LaunchArgument(name, tuple((t.node, q) for t, q in targets), desc)


DRIVER_ARGUMENTS: tuple[LaunchArgument, ...] = (
    _arg("backend", (DRIVER, "backend")),
    _arg("port", (DRIVER, "port")),
    _arg("motor", (DRIVER, "motor")),
    _arg("rate_hz", (DRIVER, "rate_hz")),
    _arg("watchdog_s", (DRIVER, "watchdog_s")),
    _arg("joint_name", (DRIVER, "joint_name")),
)
SESSION_ARGUMENTS: tuple[LaunchArgument, ...] = (
    _arg("backend", (DRIVER, "backend")),
    _arg("port", (DRIVER, "port")),
    # the driver's motor, and the nominal motor that sizes the plan
    _arg("motor", (DRIVER, "motor"), (IDENTIFICATION, "motor")),
    # the driver's rate; the recorder sizes its queues with it (the identification
    # node reads it from the driver)
    _arg("rate_hz", (DRIVER, "rate_hz"), (RECORDER, "rate_hz")),
    _arg("data_timeout_s", (IDENTIFICATION, "safety.data_timeout_s")),
    _arg("watchdog_s", (DRIVER, "watchdog_s")),
    _arg("joint_name", (DRIVER, "joint_name")),
    # the bags, and the results beside them
    _arg("output_dir", (RECORDER, "output_dir"), (IDENTIFICATION, "output_dir")),
    _arg("safe_mode", (IDENTIFICATION, "safe_mode")),
    _arg("autostart", (IDENTIFICATION, "autostart")),
    _arg("export_models", (IDENTIFICATION, "export_models")),
    _arg("session_name", (IDENTIFICATION, "session_name")),
)
# arguments whose default is the launch's own choice, not a node's
LAUNCH_DEFAULTS: dict[str, str] = {"exit_when_done": "true"}
REGISTRY_KEY = "pmdc_ident_sessions"  # the launch-wide SessionRegistry in the context
_TABLES = {t.node: t for t in (DRIVER, IDENTIFICATION, RECORDER)}


def _typed(table: ParameterTable, name: str, text: str, argument: str) -> Any:
    """``text`` (a launch argument) as the parameter's type; one line when it is not."""
    default = table[name].default
    try:
        if isinstance(default, bool):
            low = text.strip().lower()
            if low not in ("true", "false"):
                raise ValueError
            value: Any = low == "true"
        elif isinstance(default, int):
            value = int(text)
        elif isinstance(default, float):
            value = float(text)
        else:
            value = text
    except ValueError:
        msg = f"launch argument {argument}:={text!r} must be a {table[name].type_name}"
        raise PmdcError(msg) from None
    reason = table[name].refusal(value)
    if reason:
        raise PmdcError(f"launch argument {argument}:={text}: {reason}")
    return value


def overrides(
    node: str, arguments: Sequence[LaunchArgument], given: Mapping[str, str]
) -> dict[str, Any]:
    """The parameters of ``node`` the launch arguments set (those given, not ``''``)."""
    table = _TABLES[node]
    out: dict[str, Any] = {}
    for arg in arguments:
        text = given.get(arg.name, "")
        if text == "":
            continue
        for target, param in arg.targets:
            if target == node:
                out[param] = _typed(table, param, text, arg.name)
    if node == IDENTIFICATION.node:
        text = given.get("exit_when_done", LAUNCH_DEFAULTS["exit_when_done"])
        out["exit_when_done"] = _typed(table, "exit_when_done", text, "exit_when_done")
    return out


def node_parameters(
    table: ParameterTable,
    arguments: Sequence[LaunchArgument],
    given: Mapping[str, str],
    config_dir: str,
) -> list[Any]:
    """The node's ``parameters=`` list: its defaults file, ``params_file``, overrides."""
    params: list[Any] = [os.path.join(config_dir, table.config)]
    params_file = given.get("params_file", "")
    if params_file:
        if not os.path.isfile(params_file):
            raise PmdcError(f"launch argument params_file:={params_file}: no such file")
        params.append(params_file)
    values = overrides(table.node, arguments, given)
    if values:
        params.append(values)
    return params


def exit_meaning(node: str, returncode: int) -> str:
    """A process's exit status in words."""
    if returncode < 0:
        try:
            return f"killed by {signal.Signals(-returncode).name}"
        except ValueError:
            return f"killed by signal {-returncode}"
    if node == IDENTIFICATION.node:
        words = {
            ExitCode.USER_ERROR: "refused before anything moved",
            ExitCode.ABORTED: "session aborted",
            ExitCode.INTERRUPTED: "interrupted",
        }
        if returncode in words:
            return words[returncode]
    return "failed" if returncode else "done"


@dataclass
class _Session:
    processes: dict[str, int | None]  # node -> exit status (None: running)


@dataclass
class SessionRegistry:
    """The sessions of one launch (each ``session.launch.py`` included adds one) and how
    their processes ended; says once, when every one is over, which did not complete."""

    sessions: dict[str, _Session] = field(default_factory=dict)
    reported: bool = False

    def open(self, namespace: str, processes: Sequence[str]) -> str:
        """Register a session's processes; its key (the namespace, made unique)."""
        base = "/" + namespace.strip("/")
        key, k = base, 1
        while key in self.sessions:
            k += 1
            key = f"{base}#{k}"
        self.sessions[key] = _Session(dict.fromkeys(processes))
        return key

    def exited(self, key: str, node: str, returncode: int) -> None:
        self.sessions[key].processes[node] = int(returncode)

    def running(self, key: str) -> list[str]:
        """The session's processes still running."""
        return [n for n, rc in self.sessions[key].processes.items() if rc is None]

    @property
    def all_done(self) -> bool:
        return all(not self.running(k) for k in self.sessions)

    def failures(self) -> list[str]:
        """One entry per process of a session that ended with a non-zero status."""
        out = []
        for key, s in self.sessions.items():
            for node, rc in s.processes.items():
                if rc:
                    out.append(f"{key}: {node} exited with status {rc} ({exit_meaning(node, rc)})")
        return out

    def failure_report(self, shutting_down: bool) -> str | None:
        """The launch's one error line, once: when every session is over, one did not
        complete, and the launch is shutting down (so that reporting it, which makes
        ``ros2 launch`` exit 1, stops nothing that still runs)."""
        if self.reported or not shutting_down or not self.all_done:
            return None
        failed = self.failures()
        if not failed:
            return None
        self.reported = True
        n = len(self.sessions)
        bad = len({f.split(": ", 1)[0] for f in failed})
        head = f"pmdc_ident: {bad} of {n} session{'s' if n > 1 else ''} did not complete"
        return head + ": " + "; ".join(failed)


# ---------------------------------------------------------------------------
# The launch API (imported here, inside the functions: a ROS installation has it)
# ---------------------------------------------------------------------------
def registry(context: Any) -> SessionRegistry:
    """The launch-wide registry, shared by every included session launch."""
    reg = context.get_locals_as_dict().get(REGISTRY_KEY)
    if reg is None:
        reg = SessionRegistry()
        context.extend_globals({REGISTRY_KEY: reg})
    return reg


def session_actions(
    context: Any,
    *,
    tables: Sequence[ParameterTable],
    arguments: Sequence[LaunchArgument],
    config_dir: str,
) -> list[Any]:
    """The nodes of one session (or of a driver alone) and their exit handling; called
    by the launch file's ``OpaqueFunction`` with the launch context."""
    from launch.actions import EmitEvent, RegisterEventHandler
    from launch.event_handlers import OnProcessExit, OnShutdown
    from launch.events import matches_action
    from launch.events.process import SignalProcess
    from launch_ros.actions import Node

    names = [a.name for a in arguments] + ["namespace", "params_file", *LAUNCH_DEFAULTS]
    given = {n: context.launch_configurations.get(n, "") for n in names}
    namespace = given["namespace"]
    nodes = {
        t.node: Node(
            package="pmdc_ident",
            executable=t.node,
            name=t.node,
            namespace=namespace,
            output="screen",
            emulate_tty=True,
            parameters=node_parameters(t, arguments, given, config_dir),
        )
        for t in tables
    }
    reg = registry(context)
    key = reg.open(namespace, list(nodes))

    def report(ctx: Any) -> list[Any]:
        text = reg.failure_report(ctx.is_shutdown)
        if text is not None:
            # The launch service counts any error reported to its event loop: it logs the
            # line and ros2 launch exits with status 1, and nothing is stopped by it (a
            # raised exception would shut the launch down and skip other handlers).
            ctx.asyncio_loop.call_exception_handler({"message": text})
        return []

    def on_exit(node: str) -> Any:
        def handle(event: Any, ctx: Any) -> list[Any]:
            reg.exited(key, node, event.returncode)
            actions: list[Any] = []
            ident = IDENTIFICATION.node
            if node == ident and not ctx.is_shutdown:
                # this session is over: stop its own recorder (it closes the bag) and
                # driver (0 V while commanded, then open), nothing else of the launch
                for other in reg.running(key):
                    actions.append(
                        EmitEvent(
                            event=SignalProcess(
                                signal_number=signal.SIGINT,
                                process_matcher=matches_action(nodes[other]),
                            )
                        )
                    )
            return actions + report(ctx)

        return handle

    handlers = [
        RegisterEventHandler(OnProcessExit(target_action=action, on_exit=on_exit(node)))
        for node, action in nodes.items()
    ]
    handlers.append(RegisterEventHandler(OnShutdown(on_shutdown=lambda _e, ctx: report(ctx))))
    return [*nodes.values(), *handlers]
