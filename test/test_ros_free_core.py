"""Only pmdc_ident.nodes may import rclpy or ROS message packages (docs/design.md §3).

Every other module is imported in a fresh interpreter and the test checks that
no ROS module was pulled in, directly or through another module. The module
list is discovered from the source tree, so new modules are covered as they
are added.
"""

from __future__ import annotations

import json
import pkgutil
import re
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.paths import REPO

PACKAGE_DIR = REPO / "pmdc_ident"
NODES_DIR = PACKAGE_DIR / "nodes"
FORBIDDEN = (
    "rclpy",
    "std_msgs",
    "sensor_msgs",
    "diagnostic_msgs",
    "std_srvs",
    "builtin_interfaces",
    "rosidl_runtime_py",
)
_IMPORT_LINE = re.compile(
    r"^\s*(?:from|import)\s+(?:" + "|".join(FORBIDDEN) + r")\b", re.MULTILINE
)


def _ros_free_modules() -> list[str]:
    """Dotted names of pmdc_ident and every module under it except pmdc_ident.nodes."""
    names = ["pmdc_ident"]

    def walk(path: Path, prefix: str) -> None:
        for info in pkgutil.iter_modules([str(path)], prefix):
            if info.name == "pmdc_ident.nodes":
                continue
            names.append(info.name)
            if info.ispkg:
                walk(path / info.name.rsplit(".", 1)[-1], info.name + ".")

    walk(PACKAGE_DIR, "pmdc_ident.")
    return sorted(names)


MODULES = _ros_free_modules()

_PROBE = """
import importlib, json, sys
importlib.import_module(sys.argv[1])
forbidden = tuple(sys.argv[2:])
print(json.dumps(sorted(
    m for m in sys.modules if m.split(".")[0] in forbidden
)))
"""


def test_module_discovery_finds_the_package():
    assert "pmdc_ident" in MODULES
    assert not any(m == "pmdc_ident.nodes" or m.startswith("pmdc_ident.nodes.") for m in MODULES)


@pytest.mark.parametrize("module", MODULES)
def test_importing_module_loads_no_ros_package(module):
    result = subprocess.run(
        [sys.executable, "-c", _PROBE, module, *FORBIDDEN],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert result.returncode == 0, f"import {module} failed:\n{result.stderr}"
    loaded = json.loads(result.stdout.strip().splitlines()[-1])
    assert loaded == [], f"import {module} pulled in ROS modules: {loaded}"


def test_no_ros_import_line_outside_nodes():
    offenders = []
    for path in sorted(PACKAGE_DIR.rglob("*.py")):
        if NODES_DIR in path.parents:
            continue
        for match in _IMPORT_LINE.finditer(path.read_text(encoding="utf-8")):
            offenders.append(f"{path.relative_to(REPO)}: {match.group(0).strip()}")
    assert offenders == []


def test_the_import_pattern_catches_ros_imports():
    sample = "import numpy\nfrom rclpy.node import Node\n    import std_msgs.msg\n"
    assert len(_IMPORT_LINE.findall(sample)) == 2
    assert not _IMPORT_LINE.search("import rclpyish\nfrom rosbags import typesys\n")
