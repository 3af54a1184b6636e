"""One source for every node parameter: the tables generate config/*.yaml and the
tables of docs/reference.md, and this test fails when they drift."""

from __future__ import annotations

import pytest
import yaml
from helpers.paths import REPO

from pmdc_ident.core.excitation import SequenceConfig
from pmdc_ident.node_logic.session.steady_state import SteadyStateConfig
from pmdc_ident.process.parameter_tables import (
    DRIVER,
    IDENTIFICATION,
    RECORDER,
    TABLES,
    generated_files,
    main,
)


def _flat(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            out.update(_flat(v, f"{prefix}{k}."))
        else:
            out[prefix + k] = v
    return out


def test_generated_files_are_up_to_date():
    stale = [
        str(path.relative_to(REPO))
        for path, text in generated_files(REPO).items()
        if path.read_text(encoding="utf-8") != text
    ]
    assert stale == [], "run: python -m pmdc_ident.process.parameter_tables --write"


def test_the_check_reports_a_drifted_file(tmp_path, capsys):
    (tmp_path / "config").mkdir()
    for path, text in generated_files(REPO).items():
        target = tmp_path / path.relative_to(REPO)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text)
    assert main(["--check", "--repo", str(tmp_path)]) == 0
    drifted = tmp_path / "config" / "driver.yaml"
    drifted.write_text(drifted.read_text().replace("watchdog_s: 1.5", "watchdog_s: 0.7"))
    assert main(["--check", "--repo", str(tmp_path)]) == 1
    assert "config/driver.yaml" in capsys.readouterr().out


@pytest.mark.parametrize("table", TABLES, ids=lambda t: t.node)
def test_every_parameters_file_is_keyed_for_any_node_name_and_namespace(table):
    data = yaml.safe_load((REPO / "config" / table.config).read_text())
    assert list(data) == ["/**"]
    values = _flat(data["/**"]["ros__parameters"])
    assert list(values) == list(table.names)
    for p in table:
        assert values[p.name] == p.default, p.name
        assert type(values[p.name]) is type(p.default), p.name


def test_core_dataclass_defaults_are_the_tables():
    for cls, prefix in ((SequenceConfig, "sequence."), (SteadyStateConfig, "steady_state.")):
        default = cls()
        for name in default.__dataclass_fields__:
            value = getattr(default, name)
            expect = list(value) if isinstance(value, tuple) else value
            assert IDENTIFICATION[prefix + name].default == expect


def test_ranges_and_choices_refuse_with_a_reason():
    assert "must be one of open, zero" in DRIVER["safe_mode"].refusal("brake")
    assert "must lie in [0, 60]" in DRIVER["watchdog_s"].refusal(61.0)
    assert DRIVER["watchdog_s"].refusal(0.7) == ""
    assert RECORDER["rate_hz"].refusal(1000.0) == ""


def test_safe_mode_defaults_differ_only_with_the_stated_reason():
    assert DRIVER["safe_mode"].default == "open"
    assert IDENTIFICATION["safe_mode"].default == "zero"
    doc = (REPO / "docs" / "reference.md").read_text()
    assert "`safe_mode` defaults to `zero` here and to `open` in the driver on purpose" in doc
