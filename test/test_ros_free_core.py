"""Only pmdc_ident.nodes may import rclpy or ROS message packages (docs/design.md §3).

Every other module is imported in a fresh process and the test checks that no
ROS module was pulled in, directly or through another module. The module list is
discovered from the source tree, so new modules are covered as they are added.
Each process is forked from one probe interpreter that has loaded only the heavy
third-party libraries (numpy, scipy, numba, matplotlib, ...; none of them ROS, which
it checks), so 127 imports cost one interpreter start-up, not 127 (54 s of CPU); and
from a copy of it that has imported the module's parent packages, just what Python
imports first anyway (``_PROBE``; this file's CPU 10.5-11.7 -> 6.7-7.7 s, 206 modules).
Objects are frozen out of the garbage collector before each fork and the probe ends
without finalizing its libraries (its processes' CPU 6.1-6.7 -> 5.6-5.9 s; its exit
0.4-1.0 -> 0.03 s, which the last test of a worker's share waited for).
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
#: the modules that have modules under them
PACKAGES = sorted({m.rsplit(".", 1)[0] for m in MODULES if "." in m})

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

# Reads module names on stdin and prints one JSON line for each: the ROS modules that
# importing it loaded, or the error. Each module is imported in a forked child of a
# process that has imported exactly what Python imports before it: its parent packages
# (`import a.b.c` runs a, then a.b, then a.b.c). One such process serves each package
# while requests fall in its subtree, so a package's __init__ (pmdc_ident.core.diagnosis
# imports its whole pipeline) runs once per worker, not once per submodule.
_PROBE = r"""
import gc, importlib, json, os, sys, traceback
forbidden = tuple(sys.argv[1].split(","))
packages = frozenset(sys.argv[2].split(","))
for name in sys.argv[3:]:
    try:
        importlib.import_module(name)
    except ImportError:
        pass
def ros():
    return sorted(m for m in sys.modules if m.split(".")[0] in forbidden)
def say(text):
    os.write(1, text.encode() + b"\n")
def request():
    # one line from fd 0, byte by byte: a forked process must not hold another's input
    line = b""
    while not line.endswith(b"\n"):
        c = os.read(0, 1)
        if not c:
            return None
        line += c
    return line.decode().strip()
def imported(name):
    try:
        importlib.import_module(name)
        return json.dumps({"loaded": ros()})
    except BaseException:
        return json.dumps({"error": traceback.format_exc()})
def child(work):
    # work() in a forked child; what it returns (text) through a pipe, "" if it died
    r, w = os.pipe()
    gc.freeze()  # the child's collections skip what is loaded: fewer copied pages
    pid = os.fork()
    if pid == 0:
        os.close(r)
        try:
            os.write(w, work().encode())
        finally:
            os._exit(0)
    os.close(w)
    data = b""
    while chunk := os.read(r, 65536):
        data += chunk
    os.close(r)
    os.waitpid(pid, 0)
    return data.decode()
def serve(prefix, depth, name):
    # this process has imported `prefix` (depth parts; the root: the preloads only);
    # it answers the requests inside prefix and returns the first one outside
    while True:
        if name is None:
            name = request()
        if name is None or (depth and not name.startswith(prefix + ".")):
            return name
        sub = ".".join(name.split(".")[: depth + 1])
        if sub == name and name not in packages:
            say(child(lambda: imported(name)) or json.dumps({"error": "the probe died"}))
            name = None
            continue
        def server(sub=sub, name=name):
            # "next <name>": a request outside sub; "read": read one; "eof": none left
            out = imported(sub)
            if sub == name or "error" in out:
                say(out)  # a package that fails to import fails its modules too
                if "error" in out:
                    return "read"
                name = None
            rest = serve(sub, depth + 1, name)
            return "eof" if rest is None else "next " + rest
        back = child(server)
        if not back:  # died importing the package: nothing was answered
            say(json.dumps({"error": "the probe died"}))
            back = "read"
        if back == "eof":
            return None
        name = back[5:] if back.startswith("next ") else None
print(json.dumps({"loaded": ros()}), flush=True)
serve("", 0, None)
os._exit(0)  # nothing to flush (os.write): no finalization of numpy, scipy, matplotlib...
"""


@pytest.fixture(scope="module")
def probe() -> Iterator[subprocess.Popen[str]]:
    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = subprocess.Popen(
        [sys.executable, "-c", _PROBE, ",".join(FORBIDDEN), ",".join(PACKAGES), *PRELOAD],
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
