"""One rule for every unit declaration and every cell (issue 28, item 3).

A declared unit that another column contradicts is an error with the right fix, for
speed as for voltage; cells are read strictly (``1_000`` is not a thousand); a speed
beyond any motor without a position column is an error naming both units it could be.
Records from an independent RK4 motor (``helpers.motor_records``), not the package's
simulator.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.motor_records import Motor, simulate, steps, write_csv

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.errors import DataError
from pmdc_ident.dataio.csvio import read_csv
from pmdc_ident.dataio.units import InputSpec, load_input

RATE = 1000.0


@pytest.fixture(scope="module")
def record():
    v = steps([6.0, 12.0, -8.0, 0.0, 10.0], 0.3, RATE)
    return simulate(Motor(), v, RATE, noise_current=0.002, noise_speed=0.05, seed=3)


def _err(capsys, argv: list[str]) -> str:
    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_USER_ERROR, err
    assert len(err) == 1, err
    return err[0]


def test_a_declared_speed_unit_the_position_contradicts_is_an_error_with_the_right_fix(
    record, tmp_path, capsys
):
    path = write_csv(tmp_path / "run.csv", record)  # speed in rad/s, position in rad
    line = _err(capsys, ["check", str(path), "--speed-unit", "rpm"])
    assert "--speed-unit rpm" in line and "contradicts" in line
    assert line.endswith("fix: --speed-unit rad/s"), line
    assert "counts-per-rev" not in line  # the old, wrong fix


def test_the_same_from_a_sidecar(record, tmp_path, capsys):
    path = write_csv(tmp_path / "run.csv", record)
    (tmp_path / "run.csv.yaml").write_text("speed_unit: rpm\n")
    line = _err(capsys, ["identify", str(path), "--quiet"])
    assert "run.csv.yaml" in line and line.endswith("fix: --speed-unit rad/s"), line


def test_the_declaration_that_agrees_with_the_position_is_accepted(record, tmp_path):
    rpm = 30.0 / math.pi
    path = write_csv(tmp_path / "run.csv", record, scale={"speed": rpm})
    x = load_input(path, InputSpec.from_mapping({"speed_unit": "rpm"}, "test"))
    assert np.allclose(x.run.segments[0].speed, record.speed[: x.run.segments[0].n])


def test_a_wrong_position_unit_names_the_one_that_agrees(record, tmp_path, capsys):
    path = write_csv(tmp_path / "run.csv", record, scale={"position": 180.0 / math.pi})
    line = _err(capsys, ["check", str(path), "--position-unit", "rev"])
    assert line.endswith("fix: --position-unit deg"), line


def test_a_duty_cycle_beyond_its_range_is_refused(record, tmp_path, capsys):
    path = write_csv(tmp_path / "run.csv", record, scale={"voltage": 100.0 / 24.0})
    line = _err(capsys, ["check", str(path), "--voltage-unit", "duty", "--supply-v", "24"])
    assert "contradicts the voltage column" in line
    assert line.endswith("--voltage-unit duty% (a percentage)")


@pytest.mark.parametrize("cell", ["1_000", "١٢", "0x10"])
def test_cells_are_read_strictly(tmp_path, cell):
    p = tmp_path / "run.csv"
    p.write_text(f"t,voltage,current,speed\n0,1,0.1,0\n0.001,1,{cell},1\n0.002,1,0.2,2\n")
    with pytest.raises(DataError, match="line 3: 'current' is not a number"):
        read_csv(p)


def test_a_sidecar_number_is_read_strictly(record, tmp_path, capsys):
    path = write_csv(tmp_path / "run.csv", record)
    (tmp_path / "run.csv.yaml").write_text("voltage_unit: duty\nsupply_v: '2_4'\n")
    line = _err(capsys, ["check", str(path)])
    assert "supply-v must be a positive number" in line


def test_speed_in_deg_s_without_position_is_an_error_naming_both_units(record, tmp_path, capsys):
    path = write_csv(
        tmp_path / "run.csv", record, scale={"speed": 180.0 / math.pi}, drop=("position",)
    )
    assert np.max(np.abs(record.speed)) * 180 / math.pi > 3000  # beyond any motor in rad/s
    rc = main(["check", str(path)])
    out = capsys.readouterr().out
    assert rc == EXIT_USER_ERROR
    line = next(x for x in out.splitlines() if "speed-unit" in x)
    assert line.strip().startswith("error: speed-unit"), line
    assert "--speed-unit rpm" in line and "--speed-unit deg/s" in line
