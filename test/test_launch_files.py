"""The launch files' descriptions and decisions, inspected without a ROS installation.

The PyPI set has no ``launch``/``launch_ros``: a shim of the few classes the launch
files and :mod:`pmdc_ident.process.launching` use records what they are given, so each
file's ``generate_launch_description()`` really runs, its ``OpaqueFunction`` is called
with a stand-in launch context, and the process-exit and shutdown handlers it
registers are called with stand-in events. Checked: executables that exist, parameters
files keyed ``/**`` (so they reach a namespaced node), launch arguments that override
only when given, typed, over ``params_file``; two sessions in one launch stopping only
their own nodes; a failed session reported once, when every session is over (what
makes ``ros2 launch`` exit 1). Running them under the real ``ros2 launch`` is recorded
in the closing notes of issues 12 and 24.
"""

from __future__ import annotations

import ast
import importlib.util
import re
import signal
import sys
import types
from pathlib import Path
from typing import Any

import pytest
import yaml
from helpers.paths import REPO

from pmdc_ident.core.errors import PmdcError
from pmdc_ident.process.launching import LAUNCH_DEFAULTS, REGISTRY_KEY
from pmdc_ident.process.parameter_tables import DRIVER, IDENTIFICATION, RECORDER

TABLES = {t.node: t for t in (DRIVER, IDENTIFICATION, RECORDER)}


class _Recorded:
    """Any launch object: keeps its arguments."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


class LaunchConfiguration(_Recorded):
    @property
    def name(self) -> str:
        return self.args[0]


class DeclareLaunchArgument(_Recorded):
    @property
    def name(self) -> str:
        return self.args[0]

    @property
    def default(self) -> str:
        return self.kwargs["default_value"]


class OpaqueFunction(_Recorded):
    def __call__(self, context: Context) -> list[Any]:
        return self.kwargs["function"](context, **self.kwargs.get("kwargs", {}))


class Node(_Recorded):
    @property
    def parameters(self) -> list[Any]:
        return self.kwargs["parameters"]


class OnProcessExit(_Recorded):
    pass


class OnShutdown(_Recorded):
    pass


class RegisterEventHandler(_Recorded):
    pass


class SignalProcess(_Recorded):
    @property
    def target(self) -> Any:
        return self.kwargs["process_matcher"].action


class EmitEvent(_Recorded):
    pass


class GroupAction(_Recorded):
    pass


class IncludeLaunchDescription(_Recorded):
    pass


class LaunchDescription(_Recorded):
    @property
    def entities(self) -> list[Any]:
        return list(self.args[0])


class _Matcher:
    def __init__(self, action: Any) -> None:
        self.action = action


class _Loop:
    def __init__(self) -> None:
        self.errors: list[str] = []

    def call_exception_handler(self, context: dict[str, Any]) -> None:
        self.errors.append(context["message"])


class Context:
    """The launch context as the code uses it: configurations, globals, loop."""

    def __init__(self, **configurations: str) -> None:
        self.launch_configurations = dict(configurations)
        self.globals: dict[str, Any] = {}
        self.is_shutdown = False
        self.asyncio_loop = _Loop()

    def get_locals_as_dict(self) -> dict[str, Any]:
        return dict(self.globals)

    def extend_globals(self, values: dict[str, Any]) -> None:
        self.globals.update(values)


class _Exited:
    def __init__(self, returncode: int) -> None:
        self.returncode = returncode


def _shim(share: Path) -> dict[str, types.ModuleType]:
    mods: dict[str, types.ModuleType] = {}

    def module(name: str, **attrs: Any) -> None:
        m = types.ModuleType(name)
        m.__dict__.update(attrs)
        mods[name] = m

    module("launch", LaunchDescription=LaunchDescription)
    module("launch.actions", DeclareLaunchArgument=DeclareLaunchArgument,
           OpaqueFunction=OpaqueFunction, EmitEvent=EmitEvent,
           RegisterEventHandler=RegisterEventHandler, GroupAction=GroupAction,
           IncludeLaunchDescription=IncludeLaunchDescription)  # fmt: skip
    module("launch.substitutions", LaunchConfiguration=LaunchConfiguration)
    module("launch.launch_description_sources", PythonLaunchDescriptionSource=_Recorded)
    module("launch.event_handlers", OnProcessExit=OnProcessExit, OnShutdown=OnShutdown)
    module("launch.events", matches_action=_Matcher)
    module("launch.events.process", SignalProcess=SignalProcess)
    module("launch_ros")
    module("launch_ros.actions", Node=Node)
    module("ament_index_python")
    module("ament_index_python.packages", get_package_share_directory=lambda _pkg: str(share))
    return mods


@pytest.fixture
def describe(monkeypatch: pytest.MonkeyPatch):
    """``describe(name)``: ``launch/<name>``'s description, against the shim, with the
    repository standing in for the installed share directory."""
    for mod_name, mod in _shim(REPO).items():
        monkeypatch.setitem(sys.modules, mod_name, mod)

    def run(name: str) -> LaunchDescription:
        path = REPO / "launch" / name
        spec = importlib.util.spec_from_file_location(f"launch_file_{path.stem}", path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module.generate_launch_description()

    return run


def _arguments(ld: LaunchDescription) -> dict[str, DeclareLaunchArgument]:
    return {e.name: e for e in ld.entities if isinstance(e, DeclareLaunchArgument)}


def _launch(ld: LaunchDescription, context: Context, **given: str) -> list[Any]:
    """What the launch file starts for these arguments (the others at their defaults)."""
    for name, arg in _arguments(ld).items():
        context.launch_configurations.setdefault(name, given.get(name, arg.default))
    (opaque,) = [e for e in ld.entities if isinstance(e, OpaqueFunction)]
    return opaque(context)


def _nodes(actions: list[Any]) -> dict[str, Node]:
    return {a.kwargs["name"]: a for a in actions if isinstance(a, Node)}


def _handlers(actions: list[Any]) -> tuple[dict[Any, Any], Any]:
    """(node action -> its process-exit callable, the shutdown callable)."""
    exits, shutdown = {}, None
    for a in actions:
        if isinstance(a, RegisterEventHandler):
            (h,) = a.args
            if isinstance(h, OnProcessExit):
                exits[h.kwargs["target_action"]] = h.kwargs["on_exit"]
            else:
                shutdown = h.kwargs["on_shutdown"]
    return exits, shutdown


def _signalled(actions: list[Any]) -> list[Any]:
    out = []
    for a in actions:
        assert isinstance(a, EmitEvent)
        ev = a.kwargs["event"]
        assert ev.kwargs["signal_number"] == signal.SIGINT
        out.append(ev.target)
    return out


def _console_scripts() -> set[str]:
    tree = ast.parse((REPO / "setup.py").read_text())
    scripts = [
        n.value
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and " = " in n.value
    ]
    return {s.split(" = ")[0] for s in scripts}


@pytest.mark.parametrize("name", ["driver.launch.py", "session.launch.py"])
def test_launch_nodes_run_installed_executables_with_their_parameters_files(name, describe):
    ld = describe(name)
    args = _arguments(ld)
    assert {"namespace", "params_file"} <= set(args)
    assert all(a.default == LAUNCH_DEFAULTS.get(a.name, "") for a in args.values())
    nodes = _nodes(_launch(ld, Context()))
    assert set(nodes) == ({"driver_node"} if name.startswith("driver") else set(TABLES))
    for node_name, node in nodes.items():
        kw, table = node.kwargs, TABLES[node_name]
        assert kw["package"] == "pmdc_ident" and kw["executable"] in _console_scripts()
        assert kw["namespace"] == ""
        files = [p for p in node.parameters if not isinstance(p, dict)]
        assert files == [str(REPO / "config" / table.config)]
        data = yaml.safe_load(Path(files[0]).read_text())
        assert list(data) == ["/**"], f"{files[0]} must be keyed /** to reach a namespaced node"
        # nothing given: nothing overridden but the launch's own choice
        overrides = [p for p in node.parameters if isinstance(p, dict)]
        expected = [{"exit_when_done": True}] if node_name == "identification_node" else []
        assert overrides == expected


def test_given_arguments_override_typed_over_the_params_file(describe, tmp_path):
    """rate_hz, data_timeout_s, params_file, namespace (issue 24): each reaches its
    nodes with the node's type, after the package defaults and the params file."""
    params = tmp_path / "rig.yaml"
    params.write_text("/**:\n  ros__parameters:\n    settle_s: 1.0\n")
    ld = describe("session.launch.py")
    given = {"rate_hz": "500", "data_timeout_s": "2.5", "watchdog_s": "2",
             "params_file": str(params), "namespace": "left_wheel",
             "joint_name": "left_wheel_joint", "autostart": "False"}  # fmt: skip
    nodes = _nodes(_launch(ld, Context(), **given))
    for node in nodes.values():
        assert node.kwargs["namespace"] == "left_wheel"
        assert node.parameters[1] == str(params)
    assert nodes["driver_node"].parameters[2] == {
        "rate_hz": 500.0,
        "watchdog_s": 2.0,
        "joint_name": "left_wheel_joint",
    }
    assert nodes["recorder_node"].parameters[2] == {"rate_hz": 500.0}
    assert nodes["identification_node"].parameters[2] == {
        "safety.data_timeout_s": 2.5,
        "autostart": False,
        "exit_when_done": True,
    }


@pytest.mark.parametrize(
    ("given", "fragment"),
    [
        ({"rate_hz": "fast"}, "launch argument rate_hz:='fast' must be a float"),
        ({"data_timeout_s": "0"}, "safety.data_timeout_s must lie in [0.01, 60]"),
        ({"export_models": "yes"}, "export_models:='yes' must be a bool"),
        ({"params_file": "/no/such.yaml"}, "params_file:=/no/such.yaml: no such file"),
    ],
)
def test_a_bad_launch_argument_is_one_line_naming_it(describe, given, fragment):
    with pytest.raises(PmdcError) as err:
        _launch(describe("session.launch.py"), Context(), **given)
    assert fragment in str(err.value) and "\n" not in str(err.value)


def test_two_sessions_in_one_launch_stop_only_their_own_nodes(describe):
    """The first session to finish stops its recorder and driver, nothing else; a
    session that did not complete is reported once, when both are over (issue 24)."""
    ctx = Context()
    wheels = {}
    for side in ("left", "right"):
        actions = _launch(describe("session.launch.py"), ctx, namespace=f"{side}_wheel")
        ctx.launch_configurations.clear()  # a scoped include: nothing leaks
        wheels[side] = (_nodes(actions), *_handlers(actions))
    left, left_exit, shutdown = wheels["left"]
    right, right_exit, _ = wheels["right"]
    ident = "identification_node"
    # the left wheel completes first: only its own recorder and driver are stopped
    done = left_exit[left[ident]](_Exited(0), ctx)
    assert set(_signalled(done)) == {left["recorder_node"], left["driver_node"]}
    for node in ("recorder_node", "driver_node"):
        assert left_exit[left[node]](_Exited(0), ctx) == []
    # the right wheel's session aborts (status 3): its own nodes stop
    aborted = right_exit[right[ident]](_Exited(3), ctx)
    assert set(_signalled(aborted)) == {right["recorder_node"], right["driver_node"]}
    for node in ("recorder_node", "driver_node"):
        right_exit[right[node]](_Exited(0), ctx)
    assert ctx.asyncio_loop.errors == []  # the launch is not shutting down: nothing yet
    # everything exited: the launch goes idle and shuts down; the failure is reported once
    ctx.is_shutdown = True
    assert shutdown(None, ctx) == [] and wheels["right"][2](None, ctx) == []
    assert ctx.asyncio_loop.errors == [
        "pmdc_ident: 1 of 2 sessions did not complete: /right_wheel: identification_node "
        "exited with status 3 (session aborted)"
    ]
    assert REGISTRY_KEY in ctx.globals


def test_ctrl_c_leaves_the_stopping_to_the_launch_and_reports_the_interruption(describe):
    ctx = Context()
    actions = _launch(describe("session.launch.py"), ctx)
    nodes, exits, shutdown = _nodes(actions), *_handlers(actions)
    ctx.is_shutdown = True  # Ctrl-C: ros2 launch signals every process itself
    assert shutdown(None, ctx) == [] and ctx.asyncio_loop.errors == []  # all still running
    assert exits[nodes["identification_node"]](_Exited(130), ctx) == []
    exits[nodes["recorder_node"]](_Exited(0), ctx)
    assert ctx.asyncio_loop.errors == []
    exits[nodes["driver_node"]](_Exited(0), ctx)  # the last one: reported now
    (error,) = ctx.asyncio_loop.errors
    assert error.endswith("/: identification_node exited with status 130 (interrupted)")


def test_a_completed_session_reports_nothing(describe):
    ctx = Context()
    actions = _launch(describe("driver.launch.py"), ctx)
    (driver,), exits, shutdown = _nodes(actions).values(), *_handlers(actions)
    ctx.is_shutdown = True
    exits[driver](_Exited(0), ctx)
    shutdown(None, ctx)
    assert ctx.asyncio_loop.errors == []


def test_two_motors_launch_includes_two_scoped_sessions(describe):
    ld = describe("two_motors.launch.py")
    groups = [e for e in ld.entities if isinstance(e, GroupAction)]
    assert len(groups) == 2 and all(g.kwargs["scoped"] for g in groups)
    seen = []
    for g in groups:
        (include,) = g.args[0]
        (source,) = include.args
        assert source.args[0] == str(REPO / "launch" / "session.launch.py")
        given = dict(include.kwargs["launch_arguments"])
        seen.append((given["namespace"], given["joint_name"]))
    assert seen == [("left_wheel", "left_wheel_joint"), ("right_wheel", "right_wheel_joint")]


def test_launch_files_name_no_default_of_their_own():
    """Defaults come from the parameter tables: no literal a node also declares."""
    literals = {"sim", "seed000_ebike", "1000.0", "zero", "open", "pmdc_sessions"}
    for path in sorted((REPO / "launch").glob("*.launch.py")):
        code = ast.parse(path.read_text())
        found = {
            n.value for n in ast.walk(code) if isinstance(n, ast.Constant) and n.value in literals
        }
        assert found == set(), f"{path.name}: {found}"
        assert not re.search(r"\bdriver_node:", path.read_text())


def test_the_integration_guide_names_every_launch_argument():
    from pmdc_ident.process.launching import DRIVER_ARGUMENTS, SESSION_ARGUMENTS

    guide = (REPO / "docs" / "integration.md").read_text()
    names = {a.name for a in (*SESSION_ARGUMENTS, *DRIVER_ARGUMENTS)} | {"namespace"}
    missing = sorted(n for n in names | set(LAUNCH_DEFAULTS) if f"`{n}`" not in guide)
    assert missing == [], f"docs/integration.md does not describe {missing}"
