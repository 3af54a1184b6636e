"""Issue 22's foreign-shapes corpus: records the project's simulator did not make.

Each record (``helpers/foreign.py``: scipy's ``solve_ivp`` on equations written there,
or MuJoCo's ``<dcmotor>``) breaks an assumption the tool used to make without looking;
each test asserts the outcome the assumption register promises (``docs/assumptions.md``):
the parameters within their intervals or flagged with the reason and what to record,
and the exact line where the register changes the treatment. On every record: no
confident-wrong parameter (outside its 95 % interval by more than 3 standard errors
while not flagged), a motor file that ``export-model`` accepts, no advice beyond what
hardware offers.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from helpers.foreign import ForeignRecord, confident_wrong, record_by_name

from pmdc_ident.cli import main

_CACHE: dict[str, ForeignRecord] = {}


def rec(name: str) -> ForeignRecord:
    if name not in _CACHE:
        _CACHE[name] = record_by_name(name)
    return _CACHE[name]


def identify(r: ForeignRecord, tmp_path: Path, capsys, *extra: str) -> tuple[dict, str]:
    """``pmdc-ident identify`` on the record: its JSON, its printed text; the motor file it
    writes goes through ``export-model``, and no advice names a rate beyond 100 kHz."""
    csv = r.write(tmp_path / f"{r.name}.csv")
    js, ym = tmp_path / f"{r.name}.json", tmp_path / f"{r.name}.yaml"
    rc = main(["identify", str(csv), "--json", str(js), "--yaml", str(ym), *r.options, *extra])
    cap = capsys.readouterr()
    text = cap.out + cap.err
    assert rc == 0, text
    doc = json.loads(js.read_text())
    assert confident_wrong(doc["parameters"], r.truth) == [], text
    assert main(["export-model", str(ym), "--mujoco", str(tmp_path / "m.xml")]) == 0
    capsys.readouterr()
    for value, unit in re.findall(r"(\d[\d.e+]*)\s*(k?Hz)", text):
        assert float(value) * (1e3 if unit == "kHz" else 1.0) <= 100e3, text
    return doc, text


def diagnose(r: ForeignRecord, tmp_path: Path, capsys) -> dict:
    csv = r.write(tmp_path / f"{r.name}.csv")
    js = tmp_path / f"{r.name}.diag.json"
    assert main(["diagnose", str(csv), "--json", str(js), "--quiet"]) == 0
    capsys.readouterr()
    return json.loads(js.read_text())


def reading(doc: dict) -> list[tuple[str, bool]]:
    return [(s["label"], s["continues"]) for s in doc["assumptions_checked"]["segments"]]


def test_joined_runs_are_separate_runs_and_diagnose_as_with_gaps(tmp_path, capsys):
    """Three runs from rest joined with a clock that runs on (MuJoCo's dcmotor): each
    labelled segment is a separate run, said once; diagnose gives the same verdict as on
    the same runs with 1 s between them (no_gap: they are clean), and identify and
    diagnose read the segments alike. Before issue 22: `unexplained`, gap ~1.9e5."""
    joined, gapped = rec("concatenated"), rec("concatenated_gaps")
    doc, text = identify(joined, tmp_path, capsys)
    lines = [ln for ln in text.splitlines() if "continuity:" in ln]
    assert len(lines) == 1, text
    assert "step_down, prbs start one sample period after the segment before" in lines[0]
    assert "speed 298" in lines[0] and "separate runs" in lines[0]
    assert reading(doc) == [("step_up", False), ("step_down", False), ("prbs", False)]
    assert doc["assumptions_checked"]["register"]["continuity"]["status"] == "changed"
    for name in ("R", "Ke", "J"):
        assert doc["parameters"][name]["value"] == pytest.approx(joined.truth[name], rel=0.01)
    verdicts = []
    for r in (joined, gapped):
        d = diagnose(r, tmp_path, capsys)
        verdicts.append((d["verdict"]["status"], d["verdict"]["effects"]))
        assert reading(d) == reading(doc)
        units = d["holdout"]["by_signal"]["current"]
        assert units["unit"] == "A" and units["times_noise_before"] < 2.0
    assert verdicts == [("no_gap", []), ("no_gap", [])]


def test_a_position_that_restarts_with_each_run_is_not_a_wrap(tmp_path, capsys):
    """Three forward runs, no labels, the encoder zeroed at each start. Before issue 22:
    `error: position-wrap ... fix: --position-unit counts --counts-per-rev 82`."""
    r = rec("position_restarts")
    doc, text = identify(r, tmp_path, capsys)
    assert "position-wrap" not in text and "counts-per-rev" not in text
    assert "a new run starts with the rotor at rest" in text
    assert "a position that restarts with a run is not a wrap" in text
    labels = reading(doc)
    assert [c for _, c in labels].count(False) >= 3  # three runs, each from its own start
    for name in ("R", "Ke", "J"):
        assert doc["parameters"][name]["value"] == pytest.approx(r.truth[name], rel=0.01)
    assert main(["check", str(tmp_path / f"{r.name}.csv")]) == 0
    capsys.readouterr()


def test_index_based_time_keeps_a_real_session_continuous(tmp_path, capsys):
    """One continuous session written with t = index / fs: every boundary is a real
    continuation and stays one (no continuity line)."""
    r = rec("index_time")
    doc, text = identify(r, tmp_path, capsys)
    assert "continuity" not in text
    assert [c for _, c in reading(doc)] == [False, True, True, True]
    for name in ("R", "L", "Ke", "J"):
        assert doc["parameters"][name]["value"] == pytest.approx(r.truth[name], rel=0.01)


def test_a_filtered_current_on_a_fast_armature_flags_l(tmp_path, capsys):
    """L/R = 0.2 ms at 1 kHz behind a 1 ms RC current filter: the current reads as
    L = 1.08 mH (+440 % with a +-7 % interval before issue 22); now the current and the
    speed are heard apart and disagree on L: flagged, with what to record."""
    r = rec("filtered_current_fast_l")
    doc, _ = identify(r, tmp_path, capsys)
    L = doc["parameters"]["L"]
    assert not L["identifiable"] and L["ci95"] is None
    assert "the current and the speed tell different motors" in L["reason"]
    assert "record the current before any filter" in L["reason"]


def test_a_step_from_rest_at_500_hz_gives_one_message_for_b(tmp_path, capsys):
    """A coreless motor (MuJoCo's dcmotor with a Coulomb friction loss), one 8 V step at
    500 Hz: one steady speed cannot tell viscous from constant friction; B is flagged
    in one message, J's interval covers either split; L/R = 0.14 ms against a 2 ms
    sample: L's interval includes the sub-sample timing no record shows."""
    r = rec("step_500hz")
    doc, _ = identify(r, tmp_path, capsys)
    B = doc["parameters"]["B"]
    assert not B["identifiable"] and "one steady speed" in B["reason"]
    assert "a staircase" in B["reason"]
    J = doc["parameters"]["J"]
    assert J["ci95"][0] <= r.truth["J"] <= J["ci95"][1]
    assert "friction's split" in J["reason"]
    L = doc["parameters"]["L"]
    assert "timing" in L["reason"] or not L["identifiable"]


def test_a_speed_sensor_with_its_own_lag_leaves_no_parameter_confidently_wrong(tmp_path, capsys):
    """A tachogenerator with a 4 ms lag (tau_m 20 ms): the residuals are not white, the
    misfit-robust checks run and flag what disagrees (identify() asserts no
    confident-wrong parameter)."""
    r = rec("speed_lag")
    doc, _ = identify(r, tmp_path, capsys)
    checked = doc["assumptions_checked"]["register"]
    assert checked["white-residuals"]["status"] == "changed" or any(
        checked[k]["status"] == "changed" for k in ("parts-agree", "electrical-resolution")
    )
    assert any(not doc["parameters"][n]["identifiable"] for n in ("R", "L", "J"))


def test_a_start_from_rest_with_the_first_level_on_gives_a_model_export_accepts(tmp_path, capsys):
    """A staircase from rest whose first sample already carries 2 V, speed in counts of
    a 28-count encoder, a winding that heats: every value in the motor file is a
    motor's (export-model accepts it) and no advice names a rate beyond hardware."""
    r = rec("rest_first_level")
    doc, text = identify(r, tmp_path, capsys)
    for name in ("R", "L", "Ke", "J", "B"):
        assert doc["parameters"][name]["value"] > 0
    assert doc["parameters"]["L"]["value"] > 1e-9
    assert "already on" in text


def test_a_traction_motor_drawing_200_a_is_not_milliamps(tmp_path, capsys):
    """A 1.5 kW, 48 V traction motor (R 0.05 ohm) drawing ~214 A (95th percentile).
    Before issue 22: `error: current-unit: current reaches 214 A ... milliamps?`."""
    r = rec("traction_48v")
    doc, text = identify(r, tmp_path, capsys)
    assert "current-unit" not in text
    for name in ("R", "Ke", "J"):
        assert doc["parameters"][name]["value"] == pytest.approx(r.truth[name], rel=0.02)


def test_an_8_level_staircase_in_one_segment_gives_its_levels(tmp_path, capsys):
    """Eight voltage levels recorded as one labelled `staircase` segment. Before issue 22:
    `classical chain skipped: the staircase needs at least 3 steady levels, got 1`."""
    r = rec("staircase_one_segment")
    doc, text = identify(r, tmp_path, capsys)
    assert "at least 3 steady levels" not in text
    assert "holds 8 voltage levels" in text
    classical = doc["methods"]["classical"]["values"]
    assert classical["Ke"] == pytest.approx(r.truth["Ke"], rel=0.01)
    assert classical["coulomb_friction.torque_nm"] == pytest.approx(2e-3, rel=0.05)
    status = doc["assumptions_checked"]["register"]["staircase-levels"]["status"]
    assert status == "changed"
