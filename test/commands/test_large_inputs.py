"""Large and unbounded inputs (issue 28, item 5): a long record is checked on every sample
and fitted on a representative subset of its segments; absurd option values are one line.

The speed figures (a 3.7 M-row log) are a benchmark, not a test:
``benchmarks/bench_large_input.py``. Here the long-record rule runs on a small record
with the threshold lowered.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import pmdc_ident.app.inputs as inputs_mod
from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.data import Run, link_history
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio.csvio import write_csv

SESSION = SequenceConfig(
    staircase_levels=2,
    staircase_hold_tau=8.0,
    step_hold_tau=8.0,
    sweep_duration_tau=20.0,
    coast_spinup_tau=4.0,
    coast_open_s=0.5,
)


@pytest.fixture(scope="module")
def long_log(tmp_path_factory):
    """Four sessions back to back as one unlabeled log, two samples dropped in the last."""
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, 1e-3, SESSION)
    t0, p0, t = 0.0, 0.0, []
    cols: dict[str, list[np.ndarray]] = {
        k: [] for k in ("voltage", "current", "position", "speed")
    }
    for seed in range(4):
        run = synthesize_run(spec.model, plan, spec.sensors, seed=seed)
        first = run.segments[0]
        for s in run.segments:
            t.append(s.t - first.t[0] + t0)
            for k in cols:
                cols[k].append(getattr(s, k) + (p0 - first.position[0] if k == "position" else 0))
        t0 = t[-1][-1] + 1e-3
        p0 = cols["position"][-1][-1]
    arrays = {k: np.concatenate(v) for k, v in cols.items()}
    tt = np.concatenate(t)
    keep = np.ones(tt.size, dtype=bool)
    keep[tt.size - 400 : tt.size - 398] = False  # a gap late in the record
    from pmdc_ident.core.data import Segment

    seg = Segment("run", tt[keep], **{k: v[keep] for k, v in arrays.items()})
    path = tmp_path_factory.mktemp("long") / "log.csv"
    return write_csv(Run(link_history([seg]), "log"), path)


def test_a_long_record_is_checked_whole_and_fitted_on_a_subset(
    long_log, tmp_path, capsys, monkeypatch
):
    monkeypatch.setattr(inputs_mod, "LONG_SAMPLES", 8000)
    out = tmp_path / "r.json"
    argv = ["identify", str(long_log), "--quiet", "--no-holdout", "--json", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "long record:" in text and "--all-samples" in text
    doc = json.loads(out.read_text())
    fitted = doc["fit"]["segments"]
    kinds = {s.rsplit("_", 1)[0] for s in fitted}
    assert {"step_up", "step_down", "sweep", "coast"} <= kinds, fitted
    notes = doc["inputs"][str(long_log)]["notes"]
    assert any(n.startswith("long record:") for n in notes)
    # timing is checked on every sample: the late gap is found whether its segment was
    # taken or not
    codes = [f["code"] for f in doc["quality"]["findings"]]
    assert "gaps" in codes
    # the fit on the subset recovers the motor
    truth = load_motor("seed001_110v").model.params
    assert doc["parameters"]["R"]["value"] == pytest.approx(truth.R, rel=0.01)
    # --all-samples: every segment
    assert main([*argv, "--all-samples"]) == 0
    capsys.readouterr()
    assert len(json.loads(out.read_text())["fit"]["segments"]) > len(fitted)


def test_the_subset_takes_every_kind_spread_over_the_record():
    from pmdc_ident.core.data import Segment
    from pmdc_ident.dataio.units import InputSpec, LoadedInput

    segs = []
    for k in range(60):
        kind = ("step_up", "sweep", "coast")[k % 3]
        t = np.arange(100) * 1e-3 + k * 0.1
        segs.append(Segment(f"{kind}_{k // 3 + 1}", t, np.ones(100), speed=np.ones(100)))
    x = LoadedInput("x", Run(tuple(segs), "x"), InputSpec(), ())
    sub, line = inputs_mod.representative(x, budget=1200)
    labels = [s.label for s in sub.run.segments]
    assert sum(s.n for s in sub.run.segments) <= 1200 and "long record" in line
    assert {lab.rsplit("_", 1)[0] for lab in labels} == {"step_up", "sweep", "coast"}
    assert "step_up_1" in labels and "step_up_20" in labels  # first and last of a kind
    assert labels == sorted(labels, key=lambda s: [x.label for x in segs].index(s))


BOUNDS = {
    "--bootstrap 1e9": (["identify", "{csv}", "--bootstrap", "1000000000"], "--bootstrap must"),
    "--sample-rate-hz 1e12": (
        ["export-model", "seed000_ebike", "--gains", "{d}/g.yaml", "--sample-rate-hz", "1e12"],
        "--sample-rate-hz must",
    ),
    "--every -1": (["monitor", "{csv}", "--params", "seed000_ebike", "--every", "-1"], "--every"),
    "--every nan": (
        ["monitor", "{csv}", "--params", "seed000_ebike", "--every", "nan"],
        "--every must",
    ),
    "--effects ''": (["diagnose", "{csv}", "--effects", ""], "--effects lists no effect"),
    "benchmark --effects ','": (["benchmark", "--effects", ","], "--effects lists no effect"),
    "--seed -1": (["benchmark", "--seed", "-1"], "--seed must be a whole number"),
    "--jobs 10000": (["identify", "{csv}", "--batch", "{d}/b", "--jobs", "10000"], "--jobs"),
}


@pytest.mark.parametrize("case", list(BOUNDS), ids=list(BOUNDS))
def test_absurd_option_values_are_one_line(case, long_log, tmp_path, capsys):
    argv_t, match = BOUNDS[case]
    argv = [a.format(csv=long_log, d=tmp_path) for a in argv_t]
    assert main(argv) == EXIT_USER_ERROR
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err
