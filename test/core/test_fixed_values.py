"""One type of held values: --fix, the node's fix parameter, identify(fixed=) and
DiagnosisConfig(fixed=) are checked by one rule (core/fixed.FixedValues)."""

from __future__ import annotations

import pickle

import pytest

from pmdc_ident.core.diagnosis import DiagnosisConfig
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.fixed import IDENTIFY_FIXABLE, FixedValues, parse_fix
from pmdc_ident.core.identification.identify import identify
from pmdc_ident.core.params import PARAMETER_NAMES


def test_parse_fix_gives_the_checked_mapping():
    fixed = parse_fix(["L=3e-4", " R = 1.375", "coulomb_friction.torque_nm=0.02"])
    assert isinstance(fixed, FixedValues)
    assert dict(fixed) == {"L": 3e-4, "R": 1.375, "coulomb_friction.torque_nm": 0.02}
    assert parse_fix(["L=3e-4", "L=3e-4"]) == {"L": 3e-4}  # a repeat of one value is fine
    with pytest.raises(TypeError):
        fixed["L"] = 1.0  # type: ignore[index]


@pytest.mark.parametrize(
    ("items", "words"),
    [
        (["L"], "expects NAME=VALUE"),
        (["L=abc"], "is not a number"),
        (["L=nan"], "must be finite"),
        (["r=1"], "unknown parameter"),
        (["L=1e9"], "outside the physical range"),
        (["load_torque.torque_nm=2e4"], "outside the range"),
        (["L=1e-3", "L=2e-3"], "given twice with different values"),
    ],
)
def test_each_bad_item_is_one_clear_error(items, words):
    with pytest.raises(ParameterError, match=words):
        parse_fix(items)


def test_identify_checks_held_values_as_the_command_line_does():
    # before, identify checked effect fields only for being finite: a negative Coulomb
    # torque reached the fit
    with pytest.raises(ParameterError, match="outside the range"):
        identify([], fixed={"coulomb_friction.torque_nm": -0.1})
    with pytest.raises(ParameterError, match="outside the physical range"):
        identify([], fixed={"J": 1e9})


def test_the_diagnosis_holds_motor_parameters_in_their_range_only():
    assert dict(DiagnosisConfig(fixed={"L": 3e-4}).fixed) == {"L": 3e-4}
    with pytest.raises(ParameterError, match="can be fixed"):
        DiagnosisConfig(fixed={"coulomb_friction.torque_nm": 0.1})
    with pytest.raises(ParameterError, match="outside the physical range"):
        DiagnosisConfig(fixed={"L": 1e9})  # before: accepted, a unit mistake fitted around


def test_what_may_be_held_is_named_by_the_caller():
    assert set(PARAMETER_NAMES) < set(IDENTIFY_FIXABLE)
    with pytest.raises(ParameterError, match="can be fixed: R, L"):
        FixedValues({"load_torque.torque_nm": 0.1}, known=PARAMETER_NAMES)


def test_held_values_travel_to_a_worker_process_as_they_are():
    fixed = parse_fix(["L=3e-4", "load_torque.torque_nm=-0.05"])
    again = pickle.loads(pickle.dumps(fixed))
    assert isinstance(again, FixedValues) and again == fixed and hash(again) == hash(fixed)
