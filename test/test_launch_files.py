"""The launch files' descriptions, inspected without a ROS installation.

The PyPI set has no ``launch``/``launch_ros``: a shim of the few classes the launch
files use records what they are given, so each file's ``generate_launch_description()``
really runs and the nodes, parameters files, overrides, namespaces and arguments it
declares are checked: executables that exist, parameters files that exist and are
keyed ``/**`` (so they reach a namespaced node), argument defaults that are the
nodes' own (one parameter table), and override names the nodes declare. Running them
under a real ``ros2 launch`` is recorded in the closing notes of issue 12.
"""

from __future__ import annotations

import ast
import importlib.util
import re
import sys
import types
from pathlib import Path
from typing import Any

import pytest
import yaml
from helpers.paths import REPO

from pmdc_ident.nodes.parameter_tables import DRIVER, IDENTIFICATION, RECORDER

# launch arguments whose default is the launch's own choice (said in its docstring)
LAUNCH_DEFAULTS = {"exit_when_done": "true"}
TABLES = {t.node: t for t in (DRIVER, IDENTIFICATION, RECORDER)}


class _Recorded:
    """Any launch object: keeps its arguments."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args, self.kwargs = args, kwargs


class LaunchConfiguration(_Recorded):
    @property
    def name(self) -> str:
        return self.args[0]


class ParameterValue(_Recorded):
    pass


class DeclareLaunchArgument(_Recorded):
    @property
    def name(self) -> str:
        return self.args[0]

    @property
    def default(self) -> str:
        return self.kwargs["default_value"]


class Node(_Recorded):
    pass


class LaunchDescription(_Recorded):
    @property
    def entities(self) -> list[Any]:
        return list(self.args[0])


def _shim(share: Path) -> dict[str, types.ModuleType]:
    mods: dict[str, types.ModuleType] = {}

    def module(name: str, **attrs: Any) -> None:
        m = types.ModuleType(name)
        m.__dict__.update(attrs)
        mods[name] = m

    module("launch", LaunchDescription=LaunchDescription)
    module("launch.actions", DeclareLaunchArgument=DeclareLaunchArgument,
           EmitEvent=_Recorded, RegisterEventHandler=_Recorded)  # fmt: skip
    module("launch.substitutions", LaunchConfiguration=LaunchConfiguration)
    module("launch.event_handlers", OnProcessExit=_Recorded)
    module("launch.events", Shutdown=_Recorded)
    module("launch_ros")
    module("launch_ros.actions", Node=Node)
    module("launch_ros.parameter_descriptions", ParameterValue=ParameterValue)
    module("ament_index_python")
    module("ament_index_python.packages", get_package_share_directory=lambda _pkg: str(share))
    return mods


def _describe(name: str, monkeypatch: pytest.MonkeyPatch) -> LaunchDescription:
    """Run ``launch/<name>``'s generate_launch_description() against the shim, with
    the repository standing in for the installed share directory."""
    for mod_name, mod in _shim(REPO).items():
        monkeypatch.setitem(sys.modules, mod_name, mod)
    spec = importlib.util.spec_from_file_location(f"launch_file_{name}", REPO / "launch" / name)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def _nodes(ld: LaunchDescription) -> list[Node]:
    return [e for e in ld.entities if isinstance(e, Node)]


def _arguments(ld: LaunchDescription) -> dict[str, DeclareLaunchArgument]:
    return {e.name: e for e in ld.entities if isinstance(e, DeclareLaunchArgument)}


def _console_scripts() -> set[str]:
    tree = ast.parse((REPO / "setup.py").read_text())
    scripts = [
        n.value
        for n in ast.walk(tree)
        if isinstance(n, ast.Constant) and isinstance(n.value, str) and " = " in n.value
    ]
    return {s.split(" = ")[0] for s in scripts}


def _resolve(value: Any, args: dict[str, DeclareLaunchArgument]) -> Any:
    """A parameter value with launch arguments at their defaults."""
    if isinstance(value, ParameterValue):
        raw = _resolve(value.args[0], args)
        kind = value.kwargs.get("value_type", str)
        return raw.lower() == "true" if kind is bool else kind(raw)
    if isinstance(value, LaunchConfiguration):
        return args[value.name].default
    return value


@pytest.mark.parametrize("name", ["driver.launch.py", "session.launch.py"])
def test_launch_nodes_run_installed_executables_with_their_parameters_files(name, monkeypatch):
    ld = _describe(name, monkeypatch)
    args = _arguments(ld)
    nodes = _nodes(ld)
    assert nodes
    for node in nodes:
        kw = node.kwargs
        table = TABLES[kw["name"]]
        assert kw["package"] == "pmdc_ident"
        assert kw["executable"] in _console_scripts()
        assert isinstance(kw["namespace"], LaunchConfiguration)  # namespace:=... works
        assert args[kw["namespace"].name].default == ""
        files = [_resolve(p, args) for p in kw["parameters"] if not isinstance(p, dict)]
        assert len(files) == 1
        data = yaml.safe_load(Path(files[0]).read_text())
        assert list(data) == ["/**"], f"{files[0]} must be keyed /** to reach a namespaced node"
        assert Path(files[0]).name == table.config
        for override in (p for p in kw["parameters"] if isinstance(p, dict)):
            for key, value in override.items():
                assert key in table.names, f"{kw['name']} has no parameter {key}"
                if key in LAUNCH_DEFAULTS:
                    continue
                resolved = _resolve(value, args)
                default = table[key].default
                assert type(default)(resolved) == default, (key, resolved)


def test_driver_launch_arguments_default_to_the_driver_table(monkeypatch):
    args = _arguments(_describe("driver.launch.py", monkeypatch))
    for name in ("backend", "motor", "rate_hz"):
        assert args[name].default == str(DRIVER[name].default)
    assert args["params_file"].default == str(REPO / "config" / "driver.yaml")


def test_session_launch_stops_everything_when_the_identification_ends(monkeypatch):
    ld = _describe("session.launch.py", monkeypatch)
    handlers = [e for e in ld.entities if type(e) is _Recorded]
    assert len(handlers) == 1
    (on_exit,) = handlers[0].args
    ident = next(n for n in _nodes(ld) if n.kwargs["name"] == "identification_node")
    assert on_exit.kwargs["target_action"] is ident
    assert _arguments(ld)["exit_when_done"].default == LAUNCH_DEFAULTS["exit_when_done"]


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
