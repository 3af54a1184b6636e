"""``identify --batch`` / ``diagnose --batch``: many inputs, one result each, failures listed."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from pmdc_ident.cli import main
from pmdc_ident.commands.batch import expand_inputs
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio.bagio import write_bag
from pmdc_ident.dataio.csvio import write_csv

SHORT = SequenceConfig(
    staircase_levels=3, staircase_hold_tau=3.0, step_hold_tau=3.0, sweep_duration_tau=10.0
)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    """Two short seed-001 runs (a CSV and a bag), a broken CSV and a sidecar YAML."""
    d = tmp_path_factory.mktemp("batch_in")
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, 1e-3, SHORT)
    write_csv(synthesize_run(spec.model, plan, spec.sensors, seed=1), d / "a.csv")
    write_bag(synthesize_run(spec.model, plan, spec.sensors, seed=2), d / "b_bag")
    (d / "broken.csv").write_text("t,voltage\n0,1\n0.001,1\n")
    (d / "a.yaml").write_text("columns: {}\n")  # a sidecar is not an input of its own
    return d


def test_a_folder_expands_to_its_bags_and_csvs_each_once(runs) -> None:
    found = expand_inputs([str(runs), str(runs / "a.csv"), str(runs / "*.csv")])
    assert [p.name for p in found] == ["a.csv", "b_bag", "broken.csv"]
    with pytest.raises(ParameterError, match="no file matches"):
        expand_inputs([str(runs / "*.nothing")])


def test_batch_identifies_each_input_as_alone_and_lists_the_failure(runs, tmp_path, capsys):
    out = tmp_path / "results"
    rc = main(["identify", str(runs), "--batch", str(out), "--jobs", "2", "--no-holdout"])
    text = capsys.readouterr().out
    assert rc == 2  # one input failed; the others were done
    assert sorted(p.name for p in out.glob("*.json")) == ["a.json", "b_bag.json"]
    assert (out / "broken.txt").is_file()
    assert "2 of 3 inputs done" in text
    failed = [line for line in text.splitlines() if line.startswith("FAILED")]
    assert len(failed) == 1 and "broken.csv" in failed[0]
    # the same numbers as one call for that input
    alone = tmp_path / "alone.json"
    assert (
        main(["identify", str(runs / "a.csv"), "--no-holdout", "--quiet", "--json", str(alone)])
        == 0
    )
    capsys.readouterr()
    got = json.loads((out / "a.json").read_text())["parameters"]
    want = json.loads(alone.read_text())["parameters"]
    assert {k: v["value"] for k, v in got.items()} == {k: v["value"] for k, v in want.items()}


def test_batch_options_that_are_per_run_are_refused(runs, tmp_path, capsys) -> None:
    rc = main(["identify", str(runs), "--batch", str(tmp_path / "o"), "--json", "x.json"])
    assert rc == 2
    assert "--json is per run" in capsys.readouterr().err


def test_diagnose_batch_table_reads_the_verdict_of_each_json(tmp_path) -> None:
    from pmdc_ident.commands import diagnose
    from pmdc_ident.commands.batch import BatchItem, Outcome

    doc = {"verdict": {"status": "explained", "effects": ["coulomb_friction"]}}
    doc["holdout"] = {"shrink": 0.98}
    path = tmp_path / "r.json"
    path.write_text(json.dumps(doc))
    item = BatchItem(Path("r.csv"), path, tmp_path / "r.txt")
    ok = Outcome(item, True, "", 1.5, diagnose.batch_summary(path))
    bad = Outcome(BatchItem(Path("s.csv"), tmp_path / "s.json", tmp_path / "s.txt"), False, "x")
    table = diagnose.batch_table([ok, bad]).splitlines()
    assert table[1].split() == ["r.csv", "ok", "explained", "coulomb_friction", "98%", "1.5"]
    assert table[2].split()[:2] == ["s.csv", "FAILED"]
