"""`pmdc-ident identify`: outputs (table, JSON, motor YAML, report) and user errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.paths import FIXTURES

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.data import Segment
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.model import Model, simulate
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio.csvio import write_csv

FIX = FIXTURES


@pytest.fixture(scope="module")
def seed001_csv(tmp_path_factory) -> Path:
    spec = load_motor("seed001_110v")
    cfg = SequenceConfig(staircase=False, coast=False, sweep_duration_tau=20.0)
    run = synthesize_run(spec.model, plan_for_motor(spec, 2e-3, cfg), spec.sensors, seed=4)
    return write_csv(run, tmp_path_factory.mktemp("data") / "seed001.csv")


def test_identify_writes_design_json_and_a_motor_file_that_closes_the_loop(
    seed001_csv, tmp_path, capsys
):
    js, ym = tmp_path / "r.json", tmp_path / "m.yaml"
    rc = main(["identify", str(seed001_csv), "--json", str(js), "--yaml", str(ym), "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "95 % interval" in out and "Kt = Ke" in out
    assert "I(s)/V(s) = (s + 0.71" in out  # seed 001 eq. 4: s + 0.7176
    data = json.loads(js.read_text())
    for name in ("R", "L", "Ke", "J", "B"):
        p = data["parameters"][name]
        assert set(p) >= {"value", "ci95", "unit", "identifiable"}
        # Kt is not measured here: the closure Kt = Ke sets it (issue 24)
        assert p["identifiable"] is (name != "Kt"), name
        lo, hi = p["ci95"]
        assert lo <= p["value"] <= hi
    # Kt is the closure's, never a measurement (the assumption register's kt-equals-ke)
    kt = data["parameters"]["Kt"]
    assert kt["identifiable"] is False and kt["ci95"] is None
    assert kt["reason"].startswith("assumed equal to Ke")
    assert kt["value"] == data["parameters"]["Ke"]["value"]
    assert data["parameters"]["J"]["unit"] == "kg*m^2"
    assert any("Kt = Ke" in a for a in data["assumptions"])
    assert data["parameters"]["Kt"]["reason"].startswith("assumed equal to Ke")
    assert data["schema_version"] == 1
    assert {"equation_error", "output_error_linear"} <= set(data["methods"])
    assert data["validation"]["holdout"]["labels"] == ["step_down"]
    den = data["transfer_functions"]["speed_per_voltage"]["den"]
    np.testing.assert_allclose(den, [0.1042, 3.123, 60.83], rtol=0.01)
    # identify -> simulate: the written motor reproduces the true motor's step
    spec = load_motor(ym)
    true = load_motor("seed001_110v")
    v = np.full(2000, 55.0)
    a = simulate(spec.model, v, 1e-3)
    b = simulate(true.model, v, 1e-3)
    assert np.max(np.abs(a.speed - b.speed)) < 0.01 * np.max(b.speed)
    assert spec.sensors.current_noise_a == pytest.approx(0.01, rel=0.2)


def test_fixed_value_is_held_and_reported(seed001_csv, tmp_path, capsys):
    js = tmp_path / "r.json"
    rc = main(
        [
            "identify",
            str(seed001_csv),
            "--fix",
            "Kt=1.9",
            "--json",
            str(js),
            "--quiet",
            "--no-holdout",
            "--model",
            "linear",
        ]
    )
    assert rc == 0
    p = json.loads(js.read_text())["parameters"]
    assert p["Kt"]["value"] == 1.9 and p["Kt"]["ci95"] is None
    # the scale moves with Kt: J scales by 1.9/1.835
    assert p["J"]["value"] == pytest.approx(0.057419 * 1.9 / 1.835, rel=0.01)
    assert "Kt fixed" in capsys.readouterr().out


def test_seed000_tables_give_ke_and_j_with_interval(tmp_path, capsys):
    js = tmp_path / "r.json"
    rc = main(
        [
            "identify",
            str(FIX / "seed000_table4.csv"),
            str(FIX / "seed000_retardation.csv"),
            "--fix",
            "R=1.375",
            "--json",
            str(js),
            "--quiet",
        ]
    )
    assert rc == 0
    p = json.loads(js.read_text())["parameters"]
    assert p["Ke"]["value"] == pytest.approx(0.0662, rel=0.01)
    lo, hi = p["J"]["ci95"]
    assert lo < p["J"]["value"] < hi < 0.00099
    assert p["L"]["identifiable"] is False and "LCR" in p["L"]["reason"]
    assert p["coulomb_friction.torque_nm"]["value"] == pytest.approx(0.0252, abs=0.001)


def test_report_writes_plots(seed001_csv, tmp_path):
    rep = tmp_path / "rep"
    rc = main(
        [
            "identify",
            str(seed001_csv),
            "--report",
            str(rep),
            "--quiet",
            "--bootstrap",
            "0",
            "--model",
            "linear",
        ]
    )
    assert rc == 0
    names = {p.name for p in rep.iterdir()}
    assert {"segment_step_up.png", "frequency_response.png", "methods.png"} <= names
    assert {"identify.json", "identified_motor.yaml"} <= names


BAD = {
    "malformed": "t,voltage,speed\n0,1,2\n0.001,x,3\n",
    "missing_columns": "t,voltage\n0,1\n0.001,1\n",
    "time_not_increasing": "t,voltage,current,speed\n0,1,0,0\n0.002,1,0,1\n0.001,1,0,2\n",
    "nan": "t,voltage,current,speed\n0,1,0,0\n0.001,1,nan,1\n",
    "no_excitation": "t,voltage,current,speed\n"
    + "".join(f"{k * 1e-3},0,0,0\n" for k in range(200)),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_input_one_clear_line_and_nonzero_exit(case, tmp_path, capsys):
    p = tmp_path / f"{case}.csv"
    p.write_text(BAD[case])
    rc = main(["identify", str(p), "--quiet"])
    err = capsys.readouterr().err
    assert rc == EXIT_USER_ERROR
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pmdc-ident identify: error:")
    assert "Traceback" not in err


@pytest.mark.parametrize("fix", ["L", "L=abc", "Q=1", "R=-1", "L=inf"])
def test_bad_fix_is_refused(seed001_csv, fix, capsys):
    rc = main(["identify", str(seed001_csv), "--fix", fix, "--quiet"])
    assert rc == EXIT_USER_ERROR
    assert "--fix" in capsys.readouterr().err


def test_missing_file_is_one_line(capsys):
    rc = main(["identify", "/nonexistent/run.csv"])
    assert rc == EXIT_USER_ERROR
    assert "no such file" in capsys.readouterr().err


def test_identify_reads_a_bag_like_the_csv(seed001_csv, tmp_path, capsys):
    bag = tmp_path / "bag"
    assert main(["export", str(seed001_csv), "--bag", str(bag)]) == 0
    js_bag, js_csv = tmp_path / "b.json", tmp_path / "c.json"
    common = ["--quiet", "--no-holdout", "--model", "linear"]
    assert main(["identify", str(bag), "--json", str(js_bag), *common]) == 0
    assert main(["identify", str(seed001_csv), "--json", str(js_csv), *common]) == 0
    capsys.readouterr()
    a = json.loads(js_bag.read_text())["parameters"]
    b = json.loads(js_csv.read_text())["parameters"]
    for name in ("R", "L", "Ke", "J", "B"):
        assert a[name]["value"] == pytest.approx(b[name]["value"], rel=1e-6)


def test_known_added_inertia_replaces_the_kt_ke_closure(tmp_path, capsys):
    """Two runs, the second with 0.03 kg*m^2 added: Kt (5 % above Ke here) is measured."""
    spec = load_motor("seed001_110v")
    p = spec.model.params
    truth = Model(p.replace(Kt=1.05 * p.Ke))
    cfg = SequenceConfig(staircase=False, coast=False, sweep_duration_tau=20.0)
    plan = plan_for_motor(spec, 2e-3, cfg)
    a = write_csv(synthesize_run(truth, plan, spec.sensors, seed=1), tmp_path / "a.csv")
    loaded = Model(truth.params.replace(J=p.J + 0.03))
    b = write_csv(synthesize_run(loaded, plan, spec.sensors, seed=2), tmp_path / "b.csv")
    js = tmp_path / "r.json"
    args = ["identify", str(a), str(b), "--added-inertia", f"{b}=0.03", "--json", str(js)]
    assert main([*args, "--quiet", "--no-holdout", "--model", "linear"]) == 0
    d = json.loads(js.read_text())
    assert d["parameters"]["Kt"]["value"] == pytest.approx(1.05 * p.Ke, rel=0.002)
    assert d["parameters"]["J"]["value"] == pytest.approx(p.J, rel=0.002)
    assert any("added inertia" in s for s in d["assumptions"])
    assert not any(s.startswith("Kt = Ke") for s in d["assumptions"])
    capsys.readouterr()


def test_current_driven_csv_fits_the_mechanical_side_given_kt(tmp_path, capsys):
    spec = load_motor("seed000_ebike")
    p = spec.model.params
    cfg = SequenceConfig(coast=False, sweep_duration_tau=10.0)
    run = synthesize_run(spec.model, plan_for_motor(spec, 2e-3, cfg), spec.sensors, seed=3)
    segs = [Segment(s.label, s.t, None, current=s.current, speed=s.speed) for s in run.segments]
    csv_path = write_csv(segs, tmp_path / "cur.csv")
    assert main(["identify", str(csv_path), "--quiet"]) == EXIT_USER_ERROR
    assert "--fix Kt=" in capsys.readouterr().err
    js = tmp_path / "r.json"
    args = ["identify", str(csv_path), "--fix", f"Kt={p.Kt}", "--json", str(js), "--quiet"]
    assert main([*args, "--no-holdout"]) == 0
    d = json.loads(js.read_text())
    assert d["model"] == "mechanical"
    assert d["parameters"]["J"]["value"] == pytest.approx(p.J, rel=0.02)
    assert d["parameters"]["coulomb_friction.torque_nm"]["value"] == pytest.approx(
        0.0256, rel=0.05
    )
    assert d["parameters"]["R"]["identifiable"] is False
    capsys.readouterr()
