"""The package's layers, enforced: a module imports only from its own layer or below.

    core <- protocol <- dataio, report, exports <- backends, benchmark, app
    <- node_logic <- commands (and cli), process <- nodes <- demo

Every ``import`` / ``from ... import`` statement of every module is read from its
syntax tree, including imports inside functions (a lazy import is still a
dependency). The layer of a module is the first component below ``pmdc_ident``.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest
from helpers.paths import REPO

PACKAGE_DIR = REPO / "pmdc_ident"

LAYERS: dict[str, int] = {
    "__init__": 0,
    "_lazy": 0,
    "_blas": 0,
    "core": 0,
    "protocol": 1,
    "dataio": 2,
    "report": 2,
    "exports": 2,
    "backends": 3,
    "benchmark": 3,
    "app": 3,
    "node_logic": 4,
    "commands": 5,
    "cli": 5,
    "process": 5,
    "nodes": 6,
    "demo": 7,
}


def _layer_of_path(path: Path) -> str:
    rel = path.relative_to(PACKAGE_DIR)
    return rel.parts[0] if len(rel.parts) > 1 else rel.stem


def _module_name(path: Path) -> str:
    rel = path.relative_to(REPO).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _imported_modules(path: Path) -> list[tuple[int, str]]:
    """(line, absolute dotted name) of every pmdc_ident import in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = _module_name(path)
    if path.name != "__init__.py":
        package = package.rsplit(".", 1)[0]
    out: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - node.level + 1]
                mod = ".".join([*base, node.module] if node.module else base)
            else:
                mod = node.module or ""
            # "from pmdc_ident import nodes" imports the subpackage nodes
            out += [(node.lineno, f"{mod}.{a.name}") for a in node.names]
    return [(ln, m) for ln, m in out if m == "pmdc_ident" or m.startswith("pmdc_ident.")]


def _layer_of_module(name: str) -> str:
    parts = name.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else "__init__"


def upward_imports(paths: list[Path]) -> list[str]:
    offenders = []
    for path in paths:
        own = _layer_of_path(path)
        for line, mod in _imported_modules(path):
            target = _layer_of_module(mod)
            if LAYERS[target] > LAYERS[own]:
                rel = path.relative_to(REPO)
                offenders.append(f"{rel}:{line}: {own} imports {mod} ({target} is above)")
    return offenders


SOURCES = sorted(PACKAGE_DIR.rglob("*.py"))


def test_every_module_has_a_layer():
    unknown = sorted({_layer_of_path(p) for p in SOURCES} - set(LAYERS))
    assert unknown == [], f"add these to LAYERS (and to docs/design.md): {unknown}"


def test_no_module_imports_a_layer_above_its_own():
    assert upward_imports(SOURCES) == []


# Inside core: identification (core/identification/) orchestrates the toolboxes below
# it; none of them may import it back (no folder-level loop).
BELOW_IDENTIFICATION = ("estimators", "quality")


def imports_of_identification(paths: list[Path]) -> list[str]:
    offenders = []
    for path in paths:
        for line, mod in _imported_modules(path):
            if mod == "pmdc_ident.core.identification" or mod.startswith(
                "pmdc_ident.core.identification."
            ):
                offenders.append(f"{path.relative_to(REPO)}:{line}: imports {mod}")
    return offenders


def test_the_toolboxes_import_nothing_from_identification():
    toolbox = [
        p for d in BELOW_IDENTIFICATION for p in sorted((PACKAGE_DIR / "core" / d).rglob("*.py"))
    ]
    assert toolbox, "no module found under core/estimators or core/quality"
    assert imports_of_identification(toolbox) == []


@pytest.mark.parametrize(
    ("source", "bad"),
    [
        ("from pmdc_ident.core.identification.estimate import ParameterEstimate\n", True),
        ("def f():\n    from pmdc_ident.core.identification import identify\n", True),
        ("from pmdc_ident.core import identification\n", True),
        ("from pmdc_ident.core.estimators.output_error import FitResult\n", False),
    ],
)
def test_the_check_catches_imports_of_identification(tmp_path, monkeypatch, source, bad):
    path = tmp_path / "pmdc_ident" / "core" / "estimators" / "probe.py"
    path.parent.mkdir(parents=True)
    path.write_text(source)
    monkeypatch.setattr(f"{__name__}.REPO", tmp_path)
    assert bool(imports_of_identification([path])) is bad


@pytest.mark.parametrize(
    ("layer", "source", "bad"),
    [
        ("core", "from pmdc_ident.backends.base import Telemetry\n", True),
        ("core", "def f():\n    import pmdc_ident.process.bringup\n", True),
        ("protocol", "from pmdc_ident.core.enums import Fault\n", False),
        ("dataio", "from pmdc_ident import commands\n", True),
        ("nodes", "from pmdc_ident.commands.identify import parse_fix\n", False),
    ],
)
def test_the_check_catches_upward_imports(tmp_path, monkeypatch, layer, source, bad):
    fake_pkg = tmp_path / "pmdc_ident"
    (fake_pkg / layer).mkdir(parents=True)
    path = fake_pkg / layer / "probe.py"
    path.write_text(source)
    monkeypatch.setattr(f"{__name__}.PACKAGE_DIR", fake_pkg)
    monkeypatch.setattr(f"{__name__}.REPO", tmp_path)
    assert bool(upward_imports([path])) is bad


# nodes/ holds only the rclpy side: Node subclasses, QoS, parameter declaration, and
# the rclpy glue every node runs through. The ROS-free code of the nodes' processes
# (bring-up, launching, domain locks, priorities, the worker, parameter tables and
# settings) lives in process/.
NODES_WITHOUT_A_NODE = {
    "__init__": "the package (one BLAS thread per node process)",
    "qos": "the QoS profiles",
    "parameters": "parameter declaration from the tables",
    "runtime": "rclpy's init, executor and signals around every node (run_node)",
    "result_topics": "the std_msgs messages of the typed result topics",
}
ROS_MODULES = ("rclpy", "std_msgs", "sensor_msgs", "diagnostic_msgs", "std_srvs")


def _defines_a_node(tree: ast.Module) -> bool:
    def named_node(base: ast.expr) -> bool:
        return (isinstance(base, ast.Name) and base.id == "Node") or (
            isinstance(base, ast.Attribute) and base.attr == "Node"
        )

    return any(
        isinstance(n, ast.ClassDef) and any(named_node(b) for b in n.bases) for n in tree.body
    )


def _imports_ros_at_top(tree: ast.Module) -> bool:
    names = []
    for n in tree.body:
        if isinstance(n, ast.Import):
            names += [a.name for a in n.names]
        elif isinstance(n, ast.ImportFrom) and not n.level:
            names.append(n.module or "")
    return any(m.split(".")[0] in ROS_MODULES for m in names)


def misplaced_in_nodes(paths: list[Path]) -> list[str]:
    out = []
    for path in paths:
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        if path.stem == "__init__":
            continue
        if not _defines_a_node(tree) and path.stem not in NODES_WITHOUT_A_NODE:
            out.append(f"{path.name}: defines no Node subclass and is not QoS/parameters")
        elif not _imports_ros_at_top(tree):
            out.append(f"{path.name}: imports no ROS (ROS-free code goes to process/)")
    return out


def test_nodes_holds_only_node_subclasses_qos_and_parameter_declaration():
    paths = sorted((PACKAGE_DIR / "nodes").glob("*.py"))
    assert {p.stem for p in paths} >= set(NODES_WITHOUT_A_NODE)
    assert misplaced_in_nodes(paths) == []


@pytest.mark.parametrize(
    ("name", "source", "bad"),
    [
        ("probe_node", "from rclpy.node import Node\n\nclass Probe(Node):\n    pass\n", False),
        ("probe_node", "import rclpy.node\n\nclass Probe(rclpy.node.Node):\n    pass\n", False),
        ("helper", "import os\n\ndef f():\n    return os.getpid()\n", True),
        ("helper", "from std_msgs.msg import Float64\n", True),  # ROS glue, no Node
        ("qos", "import os\n", True),  # allowed by name, yet ROS-free
        ("probe_node", "class Probe(Node):\n    pass\n", True),  # a Node without ROS?
    ],
)
def test_the_check_catches_misplaced_node_modules(tmp_path, name, source, bad):
    path = tmp_path / f"{name}.py"
    path.write_text(source)
    assert bool(misplaced_in_nodes([path])) is bad
