"""The assumption register (``core/assumptions.py``, ``docs/assumptions.md``): one
place that owns every modelling assumption, the check on the data, the treatment on
failure and the test with a record that violates it; every command consults it.

The corpus tests (``test_foreign_corpus.py``) hold most of the violating records; the
register entries without one there are tested here.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from helpers.motor_records import Motor, Record, simulate, steps, write_csv

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.assumptions import REGISTER, Treatment, markdown_table, segment_reading
from pmdc_ident.core.continuity import boundary_jump, restarts, step_limits
from pmdc_ident.core.data import Run, Segment, link_history
from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
from pmdc_ident.core.identification.estimate import ParameterEstimate
from pmdc_ident.core.motors import load_motor, motor_from_mapping, motor_to_yaml

ROOT = Path(__file__).resolve().parents[2]


def test_the_register_and_its_document_agree():
    doc = (ROOT / "docs" / "assumptions.md").read_text()
    assert markdown_table() in doc, "regenerate the table: core.assumptions.markdown_table()"
    ids = [a.id for a in REGISTER]
    assert len(ids) == len(set(ids))
    for a in REGISTER:
        assert a.statement and a.check and a.on_failure
        if a.treatment is Treatment.REFUSE:
            assert "exit 2" in a.on_failure


def test_every_assumption_names_a_test_that_exists():
    for a in REGISTER:
        path, _, name = a.test.partition("::")
        text = (ROOT / path).read_text()
        assert re.search(rf"^def {re.escape(name)}\(", text, re.M), a.test


# ---------------------------------------------------------------------------
# continuity judged from the samples
# ---------------------------------------------------------------------------
def _seg(label: str, t0: float, w: np.ndarray, dt: float = 1e-3) -> Segment:
    n = w.size
    return Segment(label, t0 + np.arange(n) * dt, np.full(n, 6.0), np.full(n, 0.1), speed=w)


def test_a_jump_beyond_one_samples_change_is_a_separate_run_and_a_ramp_is_not():
    up = _seg("a", 0.0, np.linspace(0.0, 300.0, 200))  # 1.5 rad/s per sample
    cont = _seg("b", 0.2, np.linspace(301.5, 400.0, 100))
    fresh = _seg("c", 0.2, np.linspace(0.0, 100.0, 100))
    limits = step_limits([up, cont])
    assert boundary_jump(up, cont, limits) is None
    jump = boundary_jump(up, fresh, step_limits([up, fresh]))
    assert jump is not None and jump.signal == "speed" and jump.before == 300.0
    linked = link_history([up, cont])
    assert linked[1].history_voltage is not None
    separate = link_history([up, fresh])
    assert separate[1].history_voltage is None and separate[1].history_heat_a2s is None
    reading = segment_reading(separate)
    assert [r["continues"] for r in reading] == [False, False]


def test_restarts_are_found_where_the_rotor_lands_at_rest():
    w = np.r_[np.linspace(0, 300, 300), np.zeros(5), np.linspace(0, 200, 300)]
    seg = _seg("run", 0.0, w)
    found = restarts(seg)
    assert [k for k, _ in found] == [300]
    # a braking that brings the rotor down over many samples is no restart
    smooth = _seg("run", 0.0, np.r_[np.linspace(0, 300, 300), np.linspace(300, 0, 300)])
    assert restarts(smooth) == []


def test_the_projects_own_sessions_stay_continuations():
    spec = load_motor("seed001_110v")
    run = synthesize_run(spec.model, plan_for_motor(spec, 1e-3), spec.sensors, seed=3)
    assert all(r["continues"] for r in segment_reading(run.segments)[1:])


# ---------------------------------------------------------------------------
# fit stage
# ---------------------------------------------------------------------------
def _two_motors(tmp_path: Path) -> Path:
    """A step on one motor and a step down on a winding 30 % more resistive, 1 s apart
    in time: one motor over the record does not hold."""
    a = simulate(
        Motor(),
        steps([0, 6], 0.2, 1000),
        1000,
        substeps=10,
        noise_current=0.005,
        noise_speed=0.05,
        seed=1,
    )
    b = simulate(
        Motor(R=2.6),
        steps([0, -6], 0.2, 1000),
        1000,
        substeps=10,
        noise_current=0.005,
        noise_speed=0.05,
        seed=2,
    )
    rec = Record(
        np.r_[a.t, b.t + a.t[-1] + 1.0],
        np.r_[a.voltage, b.voltage],
        np.r_[a.current, b.current],
        np.r_[a.speed, b.speed],
        np.r_[a.position, b.position],
        labels=["step_up"] * a.t.size + ["step_down"] * b.t.size,
    )
    return write_csv(tmp_path / "two.csv", rec, drop=("position",))


def test_parts_that_disagree_flag_the_parameter(tmp_path, capsys):
    path = _two_motors(tmp_path)
    js = tmp_path / "two.json"
    assert main(["identify", str(path), "--json", str(js), "--quiet"]) == 0
    out = capsys.readouterr().out
    doc = json.loads(js.read_text())
    R = doc["parameters"]["R"]
    assert not R["identifiable"] and R["ci95"] is None, R
    assert "disagree" in R["reason"] and "segments taken alternately" in R["reason"]
    assert "parts-agree" in out
    assert doc["assumptions_checked"]["register"]["parts-agree"]["status"] == "changed"


def test_kt_is_reported_as_assumed_not_identified(tmp_path, capsys):
    """Kt = 0.8 Ke: voltage, current and speed cannot show it; Kt is never reported as
    measured (identifiable false, no interval), J is J/Kt's; --fix Kt holds a value."""
    rec = simulate(
        Motor(Kt=0.04),
        steps([0, 6, -6, 3], 0.25, 1000),
        1000,
        substeps=10,
        noise_current=0.005,
        noise_speed=0.05,
    )
    path = write_csv(tmp_path / "kt.csv", rec, drop=("position",))
    js = tmp_path / "kt.json"
    assert main(["identify", str(path), "--json", str(js), "--quiet"]) == 0
    out = capsys.readouterr().out
    kt = json.loads(js.read_text())["parameters"]["Kt"]
    assert kt["identifiable"] is False and kt["ci95"] is None
    assert kt["reason"].startswith("assumed equal to Ke") and "--added-inertia" in kt["reason"]
    assert (
        re.search(r"^Kt .* assumed equal to Ke", out, re.M)
        and "NOT IDENTIFIABLE" not in [ln for ln in out.splitlines() if ln.startswith("Kt ")][0]
    )
    assert main(["identify", str(path), "--json", str(js), "--quiet", "--fix", "Kt=0.04"]) == 0
    capsys.readouterr()
    doc = json.loads(js.read_text())["parameters"]
    assert doc["Kt"]["reason"] == "fixed by the user"
    assert doc["J"]["value"] == pytest.approx(2e-5, rel=0.01)


def test_a_value_outside_the_physical_range_is_flagged_and_the_yaml_exports(tmp_path):
    from pmdc_ident.core.identification.fit_checks import FitChecks, _physical_range
    from pmdc_ident.core.identification.results import IdentificationResult

    spec = load_motor("seed001_110v")
    L = ParameterEstimate("L", 4.1e-10, (3e-10, 5e-10), "H", True, stderr=5e-11)
    out = FitChecks({"L": L})
    _physical_range(out)
    flagged = out.parameters["L"]
    assert not flagged.identifiable and "outside the physical range" in flagged.reason
    model = type(spec.model)(spec.model.params.replace(L=4.1e-10), spec.model.effects)
    res = IdentificationResult(("x",), "linear", model, out.parameters, (), (), {}, {}, {})
    motor = res.motor_spec("m")
    assert motor.model.params.L == 1e-9 and "written as 1e-09" in motor.description
    back = motor_from_mapping(__import__("yaml").safe_load(motor_to_yaml(motor)))
    assert back.model.params.L == 1e-9
    path = res.write_motor_yaml(tmp_path / "m.yaml")
    assert main(["export-model", str(path), "--mujoco", str(tmp_path / "m.xml")]) == 0


# ---------------------------------------------------------------------------
# diagnosis stage; the node and the monitor
# ---------------------------------------------------------------------------
def test_a_held_out_side_without_information_is_refused(tmp_path, capsys):
    """--holdout naming a stretch where nothing moves (an open armature at rest): its gap
    could show nothing, so a no_gap would mean nothing."""
    v = steps([6, -6, None], 0.3, 1000)
    rec = simulate(Motor(B=1e-3), v, 1000, substeps=10, noise_current=0.005, counts_per_rev=512)
    labels = ["step_up"] * 300 + ["step_down"] * 300 + ["open"] * 300
    rec.labels = labels
    path = write_csv(tmp_path / "h.csv", rec, drop=("speed",))
    rc = main(["diagnose", str(path), "--holdout", "open", "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == EXIT_USER_ERROR, err
    assert "held-out segments (open) carry no information" in err
    assert "--holdout should name a step, a sweep or a coast-down" in err


def _joined_run() -> Run:
    """Two runs from rest joined with a running clock (the second starts at rest)."""
    m = Motor()
    a = simulate(m, steps([0, 6], 0.2, 1000), 1000, substeps=5, noise_current=0.005, seed=1)
    b = simulate(m, steps([0, -6], 0.2, 1000), 1000, substeps=5, noise_current=0.005, seed=2)
    segs = [
        Segment("step_up", a.t, a.voltage, a.current, speed=a.speed),
        Segment("step_down", b.t + a.t[-1] + 1e-3, b.voltage, b.current, speed=b.speed),
    ]
    return Run(link_history(segs), "joined")


def test_the_identification_node_reads_a_session_through_the_register():
    from pmdc_ident.process.identify_call import identify_session_run

    out = identify_session_run(_joined_run())
    doc = json.loads(out.json_text)
    codes = [f["code"] for f in doc["quality"]["findings"]]
    assert "continuity" in codes
    assert [s["continues"] for s in doc["assumptions_checked"]["segments"]] == [False, False]
    assert doc["parameters"]["Kt"]["identifiable"] is False


def test_the_monitor_restarts_its_filters_at_a_separate_run(tmp_path, capsys):
    from pmdc_ident.dataio.csvio import write_csv as write_run

    path = write_run(_joined_run(), tmp_path / "joined.csv")
    motor = tmp_path / "m.yaml"
    spec = load_motor("seed001_110v")
    p = Motor()
    params = spec.model.params.replace(R=p.R, L=p.L, Ke=p.Ke, Kt=p.Kt, J=p.J, B=p.B)
    motor.write_text(
        motor_to_yaml(type(spec)("small", type(spec.model)(params), spec.sensors, spec.limits))
    )
    assert main(["monitor", str(path), "--params", str(motor)]) == 0
    out = capsys.readouterr().out
    assert "1 separate run(s)" in out and "the filters restart at each" in out
    assert "worst level" in out


def test_a_bag_and_a_csv_read_joined_runs_alike(tmp_path):
    """The same rule for bags, CSVs and unlabeled logs (one read path, link_history)."""
    from pmdc_ident.core.assumptions import continues
    from pmdc_ident.dataio import load_data
    from pmdc_ident.dataio.bagio import write_bag
    from pmdc_ident.dataio.csvio import write_csv as write_run

    bag = tmp_path / "joined_bag"
    write_bag(_joined_run(), bag)
    csv = write_run(_joined_run(), tmp_path / "joined.csv")
    for path in (bag, csv):
        assert [continues(s) for s in load_data(path).segments] == [False, False], path
