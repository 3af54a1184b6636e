"""The core names an option by its key; the caller chooses the words (issue 26, problem 5).

The command line says ``--fix``, the identification node ``parameter fix``: the same
error (:class:`OptionError`: key, value, reason) and the same hint read in either.
"""

from __future__ import annotations

import pickle

import pytest

from pmdc_ident.core.errors import (
    DataError,
    DataOptionError,
    OptionError,
    ParameterError,
    SignalRangeError,
    option_name,
    wording,
)
from pmdc_ident.core.fixed import parse_fix
from pmdc_ident.core.quality.information import advice_for

NODE = {"fix": "parameter fix", "column": "`pmdc-ident identify BAG --column`"}


def test_an_option_error_carries_key_value_and_reason_and_is_worded_by_the_caller():
    with pytest.raises(OptionError) as info:
        parse_fix(["R=abc"])
    exc = info.value
    assert (exc.key, exc.value) == ("fix", "abc") and isinstance(exc, ParameterError)
    assert str(exc) == "--fix R: 'abc' is not a number"  # no caller: the command line's
    assert exc.render(NODE) == "parameter fix R: 'abc' is not a number"
    with wording(NODE):
        assert str(exc) == "parameter fix R: 'abc' is not a number"
    assert str(exc) == "--fix R: 'abc' is not a number"  # the block's words end with it


def test_an_option_error_crosses_a_process_boundary_as_itself():
    exc = DataOptionError("column", "x", "expects NAME=HEADER, got 'x'")
    back = pickle.loads(pickle.dumps(exc))
    assert type(back) is DataOptionError and isinstance(back, DataError)
    assert (back.key, back.value, str(back)) == ("column", "x", str(exc))
    rng = SignalRangeError("t = 2e+12 s is beyond", signal="t", value=2e12, unit="s")
    back = pickle.loads(pickle.dumps(rng))
    assert (back.signal, back.value, back.unit, str(back)) == ("t", 2e12, "s", str(rng))


def test_a_hint_names_the_option_in_the_words_of_the_caller_running():
    cli = advice_for("L", float("nan"), tau_e=float("nan"), dt_s=1e-3)
    assert cli == "fix L from an LCR meter (--fix L=...)"  # byte for byte as before
    with wording(NODE):
        node = advice_for("L", float("nan"), tau_e=float("nan"), dt_s=1e-3)
        assert option_name("speed_unit") == "--speed-unit"  # a key the table lacks
    assert node == "fix L from an LCR meter (parameter fix L=...)"


def test_units_take_typed_options_and_refuse_in_the_callers_words():
    from pmdc_ident.dataio.units import SpeedUnit, spec_from_options

    spec = spec_from_options(column=("speed=Speed_rpm",), speed_unit="rpm", supply_v="24")
    assert spec.speed_unit is SpeedUnit.RPM and spec.supply_v == 24.0
    assert spec.column_map() == {"speed": "Speed_rpm"}
    with pytest.raises(DataOptionError) as info:
        spec_from_options(column=("speed",))
    assert info.value.key == "column" and info.value.value == "speed"
    assert str(info.value) == "--column expects NAME=HEADER (e.g. speed=Speed_rpm), got 'speed'"
    assert info.value.render(NODE).startswith("`pmdc-ident identify BAG --column` expects")


def test_a_value_beyond_any_motor_test_carries_its_signal_and_value(tmp_path):
    """The unit hint reads the error's fields, not its text (no regular expression)."""
    from pmdc_ident.dataio.units import load_input

    path = tmp_path / "epoch.csv"
    rows = "\n".join(f"{1.7e12 + k:.0f},1.0,0.1,{0.01 * k}" for k in range(50))
    path.write_text("t,voltage,current,speed\n" + rows + "\n")
    with pytest.raises(DataError) as info:
        load_input(path)
    assert str(info.value).endswith("(Unix time in ms: --time-unit ms)"), info.value
    with wording({"time_unit": "time_unit (sidecar key)"}), pytest.raises(DataError) as info:
        load_input(path)
    assert str(info.value).endswith("(Unix time in ms: time_unit (sidecar key) ms)")
