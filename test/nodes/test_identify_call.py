"""The identification worker: its warm-up covers what a session's identification runs,
and a job handed over meanwhile does not hold the node up."""

from __future__ import annotations

import sys
import time

import numpy as np
import pytest

from pmdc_ident.core._jit import HAVE_NUMBA
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor
from pmdc_ident.core.samples import DriverSamples
from pmdc_ident.node_logic.session.ports import IdentificationJob
from pmdc_ident.process.identify_call import IdentificationWorker, identify_session_run, warm_up


def _kernels() -> dict[str, int]:
    """Every numba kernel of the package loaded so far, with its number of signatures."""
    from numba.core.registry import CPUDispatcher

    found = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("pmdc_ident"):
            continue
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher):
                found[f"{name}.{attr}"] = len(value.signatures)
    return found


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")
def test_after_the_warm_up_a_session_identification_loads_no_kernel():
    spec = load_motor("seed001_110v")
    warm_up(spec)
    before = _kernels()
    # a session longer than the warm-up's, on another motor, with other noise
    other = load_motor("seed000_ebike")
    plan = plan_for_motor(other, 1e-3, SequenceConfig(staircase_levels=3, coast_open_s=0.5))
    out = identify_session_run(synthesize_run(other.model, plan, other.sensors, seed=3))
    assert out.values["R"] > 0
    assert _kernels() == before


def test_a_job_handed_to_a_worker_still_warming_up_does_not_block_the_node(tmp_path):
    n = 400_000  # ~13 MB of samples: far more than a pipe holds
    ns = np.arange(n, dtype=np.int64) * 1_000_000
    zeros = np.zeros(n)
    samples = DriverSamples(ns, zeros, ns, zeros, zeros, ns, zeros, None, markers=())
    job = IdentificationJob(samples, "s", "session s", tmp_path / "out", {})
    worker = IdentificationWorker(load_motor("seed001_110v"))
    try:
        t0 = time.monotonic()
        worker.submit(job)
        assert time.monotonic() - t0 < 0.5  # the child reads it only after its warm-up
        outcome = None
        while outcome is None and time.monotonic() - t0 < 120:
            outcome = worker.poll()
            time.sleep(0.02)
    finally:
        worker.terminate()
    assert outcome is not None and outcome.error  # no markers: refused, in one outcome
    assert "warmed up" in outcome.notes[0][1]


# -- the node's worker runs the service of `pmdc-ident identify` -------------------------
def _session_like_run(seed: int = 3):
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, 1e-3, SequenceConfig(staircase_levels=2, coast_open_s=0.3))
    return synthesize_run(spec.model, plan, spec.sensors, seed=seed, source="session")


def _timeless(doc):
    """``doc`` without wall times (``elapsed_s``)."""
    if isinstance(doc, dict):
        return {k: _timeless(v) for k, v in doc.items() if k != "elapsed_s"}
    if isinstance(doc, list):
        return [_timeless(v) for v in doc]
    return doc


def test_the_worker_writes_the_document_of_pmdc_ident_identify_json(tmp_path):
    import json

    from pmdc_ident.app.options import CLI_NAMES
    from pmdc_ident.cli import main
    from pmdc_ident.dataio.csvio import write_csv
    from pmdc_ident.dataio.units import load_input
    from pmdc_ident.process.identify_call import NODE_NAMES

    path = str(write_csv(_session_like_run(), tmp_path / "session.csv"))
    assert main(["identify", path, "--json", str(tmp_path / "cli.json"), "--quiet"]) == 0
    by_cli = json.loads((tmp_path / "cli.json").read_text())
    # the worker gets the samples (here: as the command read them), not the file
    node = identify_session_run(load_input(path).run, source=path)
    online = json.loads(node.json_text)
    assert list(online) == list(by_cli)  # the same keys, in the same order
    # the input's units: the node's samples are SI already (docs/reference.md)
    assert online["inputs"][path]["units"] == {"origin": "the node's driver samples (SI units)"}
    assert by_cli["inputs"][path]["units"] == {"origin": "command line"}
    online.pop("inputs"), by_cli.pop("inputs")
    # the same document but for the words naming an option: the node's (its ROS
    # parameter, or the command that has the option) where the command names its flag
    in_cli_words = json.dumps(_timeless(online))
    for key, flag in CLI_NAMES.items():
        in_cli_words = in_cli_words.replace(json.dumps(NODE_NAMES[key])[1:-1], flag)
    assert in_cli_words == json.dumps(_timeless(by_cli))
    assert node.yaml_text.startswith("# Motor file written by `pmdc-ident identify`")


def test_the_worker_fits_around_an_outlier_and_says_so_in_its_own_words():
    # an unattended session is not thrown away for a one-sample glitch: the worker
    # fits around it (the command's --drop-outliers) and the lines say what was left
    # out and that the command refuses it
    from dataclasses import replace

    from pmdc_ident.core.data import Run

    run = _session_like_run(seed=4)
    clean = identify_session_run(run, source="/bags/session_x")
    seg = run.segments[1]
    current = seg.current.copy()
    current[seg.n // 2] = 50.0 * float(abs(current).max())  # a one-sample glitch
    run = Run((run.segments[0], replace(seg, current=current), *run.segments[2:]), run.source)
    out = identify_session_run(run, source="/bags/session_x")
    assert "1 isolated current outlier(s) left out" in out.table
    assert "`pmdc-ident identify BAG` refuses them" in out.table
    for k in ("R", "Ke", "J"):
        assert out.values[k] == pytest.approx(clean.values[k], rel=1e-3)
