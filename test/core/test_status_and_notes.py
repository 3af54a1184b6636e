"""Codes, not words (issue 26, problem 5): the status topic's states come from one enum
mapped from the controller's phase, and a parameter's note is matched by its code."""

from __future__ import annotations

from dataclasses import replace

import pytest

from pmdc_ident.core.enums import ParameterNote, SessionStatus
from pmdc_ident.node_logic.session.controller import Phase


def test_the_status_topic_keeps_its_strings():
    # a stable interface (docs/reference.md): these strings, whatever the enum's names
    assert [s.value for s in SessionStatus] == [
        "idle",
        "preparing",
        "running",
        "identifying",
        "done",
        "failed",
        "refused",
        "stopped",
        "aborted",
    ]


def test_each_phase_publishes_its_status_and_a_finished_one_its_outcome():
    assert Phase.IDLE.status is SessionStatus.IDLE
    assert Phase.PREPARING.status is SessionStatus.PREPARING
    assert Phase.RUNNING.status is Phase.FLUSHING.status is SessionStatus.RUNNING
    assert Phase.IDENTIFYING.status is SessionStatus.IDENTIFYING
    assert Phase.FINISHED.status is None


@pytest.fixture(scope="module")
def result():
    from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
    from pmdc_ident.core.identification.identify import identify
    from pmdc_ident.core.motors import load_motor

    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, 1e-3, SequenceConfig(staircase_levels=3, coast_open_s=0.4))
    run = synthesize_run(spec.model, plan, spec.sensors, seed=5)
    return identify(run, fixed={"B": spec.model.params.B})


def test_the_fit_says_what_a_reason_is_by_code(result):
    p = result.parameters
    assert p["Kt"].notes == {ParameterNote.ASSUMED} and p["Kt"].assumed
    assert p["B"].notes == {ParameterNote.FIXED} and p["B"].method == "fixed"
    assert not p["R"].assumed and ParameterNote.FIXED not in p["R"].notes


def test_the_table_shows_a_note_by_its_code_not_its_words(result):
    r = replace(result.parameters["R"], reason="weakly identifiable: reworded", notes=frozenset())
    table = replace(result, parameters={**result.parameters, "R": r}).table()
    assert "reworded" not in table  # identifiable, no code: no note
    r = replace(r, reason="in other words", notes=frozenset({ParameterNote.WEAKLY_IDENTIFIABLE}))
    table = replace(result, parameters={**result.parameters, "R": r}).table()
    assert "in other words" in table
    # an identifiable value with the code of an assumption is still never "measured"
    kt = replace(result.parameters["Kt"], identifiable=True)
    assert kt.to_json()["identifiable"] is False
    assert replace(kt, notes=frozenset()).to_json()["identifiable"] is True
