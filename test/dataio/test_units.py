"""Columns and units of logs from other tools (``dataio/units.py``): options and sidecar."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from helpers.motor_records import Motor, simulate, steps, write_csv

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.errors import DataError
from pmdc_ident.dataio.units import InputSpec, load_input

HEADERS = {"t": "Time", "voltage": "PWM", "current": "I_mA", "speed": "RPM", "position": "Enc"}


@pytest.fixture(scope="module")
def rec():
    return simulate(Motor(), steps([6, 12, -6], 0.3, 1000), 1000, substeps=10)


def test_foreign_log_with_sidecar_reads_as_si(rec, tmp_path):
    scale = {
        "t": 1e3,
        "voltage": 1 / 24.0,
        "current": -1e3,
        "speed": 30 / math.pi,
        "position": 4096 / (2 * math.pi),
    }
    path = write_csv(tmp_path / "log.csv", rec, headers=HEADERS, scale=scale)
    (tmp_path / "log.csv.yaml").write_text(
        "columns: {t: Time, voltage: PWM, current: -I_mA, speed: RPM, position: Enc}\n"
        "time_unit: ms\nvoltage-unit: duty\nsupply_v: 24\ncurrent_unit: mA\n"
        "speed_unit: rpm\nposition_unit: counts\ncounts_per_rev: 4096\n"
    )
    x = load_input(path)
    s = x.run.segments[0]
    np.testing.assert_allclose(s.t, rec.t, atol=1e-12)
    np.testing.assert_allclose(s.voltage, rec.voltage, rtol=1e-12)
    np.testing.assert_allclose(s.current, rec.current, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(s.speed, rec.speed, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(s.position, rec.position, rtol=1e-12, atol=1e-12)
    assert any("units and columns from" in n for n in x.notes)
    assert any("current sign flipped" in n for n in x.notes)
    # the command line overrides the sidecar key by key
    over = load_input(path, InputSpec(speed_unit=None, supply_v=12.0))
    np.testing.assert_allclose(over.run.segments[0].voltage, rec.voltage / 2, rtol=1e-12)


def test_gear_ratio_reports_motor_side_and_notes_the_load_side(rec, tmp_path, capsys):
    gear = 5.0
    path = write_csv(tmp_path / "g.csv", rec, scale={"speed": 1 / gear, "position": 1 / gear})
    js = tmp_path / "g.json"
    rc = main(["identify", str(path), "--gear-ratio", "5", "--json", str(js), "--quiet"])
    assert rc == 0, capsys.readouterr()
    out = capsys.readouterr().out
    assert "load side: seen from the load side of a 5:1 gear" in out
    data = json.loads(js.read_text())
    ke = data["parameters"]["Ke"]["value"]
    assert ke == pytest.approx(0.05, rel=1e-3)  # the motor's own
    assert data["load_side"]["Ke"] == pytest.approx(5 * ke)
    assert data["load_side"]["J"] == pytest.approx(25 * data["parameters"]["J"]["value"])
    assert data["inputs"][str(path)]["units"] == {"gear_ratio": 5.0, "origin": "command line"}


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--speed-unit", "furlong"], "speed-unit: 'furlong' is not one of"),
        (["--position-unit", "counts"], "needs --counts-per-rev N"),
        (["--voltage-unit", "duty"], "--voltage-unit duty needs --supply-v V"),
        (["--column", "speed=Nope"], "no column 'Nope' for 'speed'"),
        (["--column", "sped=speed"], "'sped' is not one of"),
        (["--gear-ratio", "-2"], "gear-ratio must be a positive number"),
    ],
)
def test_bad_unit_options_are_one_line_and_exit_2(rec, tmp_path, capsys, argv, message):
    path = write_csv(tmp_path / "r.csv", rec)
    assert main(["check", str(path), *argv]) == EXIT_USER_ERROR
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err


def test_sidecar_with_an_unknown_key_is_refused(rec, tmp_path):
    path = write_csv(tmp_path / "r.csv", rec)
    (tmp_path / "r.csv.yaml").write_text("speed_units: rpm\n")
    with pytest.raises(DataError, match="unknown key 'speed_units'"):
        load_input(path)


@pytest.mark.parametrize(("unit", "factor"), [("ms", 1e3), ("us", 1e6), ("ns", 1e9)])
def test_epoch_stamps_name_their_unit_and_the_option_reads_them(
    rec, tmp_path, capsys, unit, factor
):
    """A logger's Unix time (2023) in ms, us or ns: one line naming the unit, exit 2."""
    from dataclasses import replace

    stamped = replace(rec, t=(1.7e9 + rec.t) * factor)
    path = write_csv(tmp_path / "epoch.csv", stamped)
    assert main(["check", str(path)]) == EXIT_USER_ERROR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"(Unix time in {unit}: --time-unit {unit})" in err, err
    assert main(["check", str(path), "--time-unit", unit]) == 0
