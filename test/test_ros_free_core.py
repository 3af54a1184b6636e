"""Only pmdc_ident.nodes may import rclpy or ROS message packages (docs/design.md §3).

Every other module is imported in a fresh process and the test checks that no
ROS module was pulled in, directly or through another module. The module list is
discovered from the source tree, so new modules are covered as they are added.
Each process is forked from one probe interpreter that has loaded only the heavy
third-party libraries (numpy, scipy, numba, matplotlib, ...; none of them ROS, which
it checks), so 127 imports cost one interpreter start-up, not 127 (54 s of CPU).
"""

from __future__ import annotations

import json
import os
import pkgutil
import re
import subprocess
import sys
from collections.abc import Iterator
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

# Loaded once by the probe before it forks (what is missing is skipped): not ROS.
PRELOAD = (
    "numpy",
    "scipy.linalg",
    "scipy.optimize",
    "scipy.signal",
    "scipy.sparse",
    "scipy.stats",
    "numba",
    "matplotlib.pyplot",
    "yaml",
    "rosbags.rosbag2",
    "rosbags.typesys",
    "serial",
)

# Reads module names on stdin; imports each in a forked child (a clean copy of this
# interpreter) and prints one JSON line: the ROS modules it loaded, or the error.
_PROBE = """
import importlib, json, os, sys, traceback
forbidden = tuple(sys.argv[1].split(","))
for name in sys.argv[2:]:
    try:
        importlib.import_module(name)
    except ImportError:
        pass
def ros():
    return sorted(m for m in sys.modules if m.split(".")[0] in forbidden)
print(json.dumps({"loaded": ros()}), flush=True)
for line in sys.stdin:
    r, w = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(r)
        try:
            importlib.import_module(line.strip())
            out = {"loaded": ros()}
        except BaseException:
            out = {"error": traceback.format_exc()}
        os.write(w, json.dumps(out).encode())
        os._exit(0)
    os.close(w)
    data = b""
    while chunk := os.read(r, 65536):
        data += chunk
    os.close(r)
    os.waitpid(pid, 0)
    print(data.decode() or json.dumps({"error": "the probe died"}), flush=True)
"""


@pytest.fixture(scope="module")
def probe() -> Iterator[subprocess.Popen[str]]:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.Popen(
        [sys.executable, "-c", _PROBE, ",".join(FORBIDDEN), *PRELOAD],
        cwd=REPO,
        env=env,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )
    assert proc.stdout is not None
    preloaded = json.loads(proc.stdout.readline())
    assert preloaded == {"loaded": []}, f"a preloaded library pulled in ROS: {preloaded}"
    yield proc
    proc.communicate(timeout=60)


def test_module_discovery_finds_the_package():
    assert "pmdc_ident" in MODULES
    assert not any(m == "pmdc_ident.nodes" or m.startswith("pmdc_ident.nodes.") for m in MODULES)


@pytest.mark.parametrize("module", MODULES)
def test_importing_module_loads_no_ros_package(module, probe):
    assert probe.stdin is not None and probe.stdout is not None
    probe.stdin.write(module + "\n")
    probe.stdin.flush()
    result = json.loads(probe.stdout.readline())
    assert "error" not in result, f"import {module} failed:\n{result.get('error')}"
    assert result["loaded"] == [], f"import {module} pulled in ROS modules: {result['loaded']}"


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
