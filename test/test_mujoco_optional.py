"""MuJoCo is a benchmark and export dependency, never a runtime one (issue 23).

identify, diagnose, the exports a session writes beside its bag and the nodes run
without it: no module outside the MuJoCo plant, the replay and the two commands that
simulate in MuJoCo imports it (lazy imports included), and a process that identifies,
diagnoses, writes the exports with a diagnosis and imports every node module never
even looks for it.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys

from helpers.paths import REPO

PACKAGE = REPO / "pmdc_ident"
# the only modules that import mujoco (inside the functions that simulate)
MAY_IMPORT = {
    "benchmark/mujoco_plant.py",
    "exports/mujoco_replay.py",
    "commands/benchmark.py",  # --plant mujoco: checks the package is there
    "commands/roundtrip.py",  # ... likewise
}


def _imports_mujoco(path) -> bool:  # type: ignore[no-untyped-def]
    tree = ast.parse(path.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import) and any(
            a.name.split(".")[0] == "mujoco" for a in node.names
        ):
            return True
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "mujoco":
            return True
    return False


def test_only_the_plant_the_replay_and_their_commands_import_mujoco():
    found = {str(p.relative_to(PACKAGE)) for p in PACKAGE.rglob("*.py") if _imports_mujoco(p)}
    assert found == MAY_IMPORT


PROBE = r"""
import importlib, json, pkgutil, sys, tempfile
from pathlib import Path

looked = []

class Watch:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] == "mujoco":
            looked.append(name)
        return None

sys.meta_path.insert(0, Watch())

import numpy as np
from pmdc_ident.core.diagnosis import DiagnosisConfig, diagnose
from pmdc_ident.core.identification.identify import identify
from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor
from pmdc_ident.exports import write_exports

spec = load_motor("seed001_110v")
run = synthesize_run(spec.model, plan_for_motor(spec, 2e-3), spec.sensors, seed=1)
identify(list(run.segments), sources=("probe",))
doc = diagnose([run], config=DiagnosisConfig(workers=1)).to_json()
with tempfile.TemporaryDirectory() as tmp:
    write_exports(spec, tmp, stem="identified", diagnosis=doc)
nodes = []
import pmdc_ident.nodes, pmdc_ident.process
for info in [
    *pkgutil.iter_modules(pmdc_ident.nodes.__path__, "pmdc_ident.nodes."),
    *pkgutil.iter_modules(pmdc_ident.process.__path__, "pmdc_ident.process."),
]:
    try:
        importlib.import_module(info.name)
        nodes.append(info.name)
    except ImportError as exc:  # no ROS here: the AST test covers these modules
        if "mujoco" in str(exc):
            raise
print(json.dumps({"looked": looked, "nodes": nodes}))
"""


def test_identify_diagnose_exports_and_nodes_never_look_for_mujoco():
    out = subprocess.run(
        [sys.executable, "-c", PROBE],
        capture_output=True,
        text=True,
        check=True,
        cwd=REPO,
        env={**os.environ, "OPENBLAS_NUM_THREADS": "1"},
        timeout=300,
    )
    result = json.loads(out.stdout.strip().splitlines()[-1])
    assert result["looked"] == []
    assert "pmdc_ident.process.identify_call" in result["nodes"]
