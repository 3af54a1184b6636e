"""The application service: parsed options in, documents out, refusals in the caller's
words (the command line's flags by default, the node's names when it passes them)."""

from __future__ import annotations

import pytest

from pmdc_ident.app import (
    CLI_NAMES,
    CheckOptions,
    DiagnoseOptions,
    IdentifyOptions,
    check_inputs,
    diagnose_inputs,
    identify_inputs,
)
from pmdc_ident.app.service import check_diagnose_options, check_identify_options
from pmdc_ident.core.errors import DataError, ParameterError, option_name

NAMES = {
    "ignore": "ignore_codes",
    "closure": "closure",
    "fix": "fixed",
    "added_inertia": "inertia_added",
    "effects": "tried",
}


@pytest.mark.parametrize(
    ("options", "check", "cli_words", "own_words"),
    [
        (
            IdentifyOptions(("a.csv",), ignore=("nope",)),
            check_identify_options,
            "--ignore nope",
            "ignore_codes nope",
        ),
        (
            IdentifyOptions(("a.csv",), closure="none"),
            check_identify_options,
            "--fix Kt=...",
            "fixed Kt=...",
        ),
        (
            DiagnoseOptions(("a.csv",), effects=("bogus",)),
            check_diagnose_options,
            "--effects: unknown",
            "tried: unknown",
        ),
    ],
)
def test_a_refusal_names_the_option_as_the_caller_does(options, check, cli_words, own_words):
    from dataclasses import replace

    with pytest.raises(ParameterError, match=f"^{cli_words}|{cli_words}"):
        check(options)
    with pytest.raises(ParameterError) as err:
        check(replace(options, names=NAMES))
    assert own_words in str(err.value) and "--" not in str(err.value).split(":")[0]


def test_options_are_refused_before_any_data_is_read(tmp_path):
    missing = str(tmp_path / "none.csv")  # never opened: the options are refused first
    with pytest.raises(ParameterError):
        identify_inputs(IdentifyOptions((missing,), ignore=("zzz",)))
    with pytest.raises(ParameterError):
        diagnose_inputs(DiagnoseOptions((missing,), effects=()))
    with pytest.raises(ParameterError):
        check_inputs(CheckOptions((missing,), ignore=("zzz",)))


def test_check_returns_its_lines_and_json_and_refuses_only_when_asked(tmp_path):
    from helpers.paths import REPO

    path = str(REPO / "test" / "fixtures" / "seed000_retardation.csv")  # a coast only
    shown: list[str] = []
    docs = check_inputs(CheckOptions((path,)), show=shown.append)
    assert docs.lines == shown and shown[0] == "data quality:"
    assert docs.body["sources"] == [path]
    assert docs.body["quality"]["errors"] == 1
    with pytest.raises(DataError, match=r"no-drive: .*\(--ignore CODE goes on anyway\)"):
        docs.stop_on_errors()
    ok = check_inputs(CheckOptions((path,), ignore=("no-drive",)))
    assert ok.stop_on_errors() == "ok: no errors, 1 warning(s)"


def test_the_command_line_names_every_option_it_has():
    assert all(v.startswith("--") for k, v in CLI_NAMES.items() if k != "data")


def test_options_name_an_option_by_the_one_wording_rule():
    """``InputOptions.name`` is :func:`option_name` with the options' table (issue 26: one
    source of the wording): a key the table lacks is named as the command line spells
    it, as everywhere else in the core, not by its bare key."""
    partial = IdentifyOptions(("a.csv",), names={"fix": "parameter fix"})
    assert partial.name("fix") == option_name("fix", partial.names) == "parameter fix"
    assert partial.name("added_inertia") == option_name("added_inertia", partial.names)
    assert partial.name("added_inertia") == "--added-inertia"  # was "added_inertia"
    for key, words in CLI_NAMES.items():
        assert IdentifyOptions(("a.csv",)).name(key) == words
        if key != "data":  # the command line's words are the rule's own
            assert words == option_name(key, {})
