"""``pmdc-ident plan`` (issue 25): the plan printed and written for a rig to play, a
pre-test and a plan designed from its log, and bad input as one line."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest
from helpers.plans import tiny_run

from pmdc_ident.cli import main
from pmdc_ident.core.design import plan_from_csv_text
from pmdc_ident.dataio.csvio import write_csv


def test_plan_prints_the_plan_and_writes_it_as_csv(tmp_path: Path, capsys):
    out = tmp_path / "plan.csv"
    assert (
        main(["plan", "seed001_110v", "--csv", str(out), "--json", str(tmp_path / "p.json")]) == 0
    )
    text = capsys.readouterr().out
    assert "predicted relative sd" in text and "binding limit" in text and f"wrote {out}" in text
    plan = plan_from_csv_text(out.read_text())
    assert plan.segments and plan.dt_s == pytest.approx(1e-3)
    assert not list(tmp_path.glob(".plan.csv.*"))  # no temporary file left


def test_a_pretest_and_a_plan_from_its_log(tmp_path: Path, capsys):
    assert main(["plan", "seed001_110v", "--pretest", str(tmp_path / "pre.csv")]) == 0
    pre = plan_from_csv_text((tmp_path / "pre.csv").read_text())
    assert pre.duration_s <= 2.0
    log = write_csv(tiny_run(3), tmp_path / "log.csv")
    rc = main(["plan", str(log), "--csv", str(tmp_path / "plan.csv")])
    assert rc in (0, 3)
    assert "pre-test" in capsys.readouterr().out


def test_a_pretest_log_is_read_with_its_sidecar(tmp_path: Path, capsys):
    """A pre-test logged in rpm with a sidecar saying so gives the prior that the same log
    in rad/s gives (the sidecar was ignored: Ke 9.5 times too small)."""
    import math

    log = write_csv(tiny_run(3), tmp_path / "rad.csv")
    lines = log.read_text().splitlines()
    cols = lines[0].split(",")
    keep = [k for k, c in enumerate(cols) if c != "position"]
    w = cols.index("speed")

    def row(line: str, rpm: bool) -> str:
        cells = line.split(",")
        if rpm and cells[w]:
            cells[w] = repr(float(cells[w]) * 60.0 / (2.0 * math.pi))
        return ",".join(cells[k] for k in keep)

    body = lines[1:]
    (tmp_path / "rad.csv").write_text("\n".join(row(x, False) for x in lines) + "\n")
    rpm = tmp_path / "rpm.csv"
    rpm.write_text("\n".join([row(lines[0], False), *(row(x, True) for x in body)]) + "\n")
    (tmp_path / "rpm.csv.yaml").write_text("speed_unit: rpm\n")
    ke = []
    for name in ("rad.csv", "rpm.csv"):
        out = tmp_path / f"{name}.json"
        assert main(["plan", str(tmp_path / name), "--json", str(out)]) in (0, 3)
        prior = json.loads(out.read_text())["prior"]
        ke.append(float(prior.split("Ke ")[1].split()[0]))
    capsys.readouterr()
    assert ke[1] == pytest.approx(ke[0], rel=1e-3)


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--travel-rad", "2", "-2"], "travel range"),
        (["--target", "R=abc"], "not a number"),
        (["--rate-hz", "0"], "rate-hz"),
        (["--travel-rad", "-2", "2", "--travel-margin-rad", "-1"], "--travel-margin-rad"),
        (["--start-rad", "nan"], "--start-rad"),
        (["--counts-per-rev", "-5"], "--counts-per-rev"),
        (["--speed-noise", "inf"], "--speed-noise"),
        (["--current-lag-us", "-1"], "--current-lag-us"),
        (["--reveal", "warp_drive"], "unknown"),
        (["--reveal", "cogging", "--reveal-size", "stribeck_friction=0.1"], "not in --reveal"),
        (["--reveal", "cogging", "--reveal-size", "cogging=abc"], "positive number"),
        (["--csv", "nowhere/plan.csv"], "does not exist"),
    ],
)
def test_bad_input_is_one_line_and_exit_status_2(args, match, capsys):
    assert main(["plan", "seed001_110v", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0], err


def test_the_plan_is_never_written_over_its_input(tmp_path: Path, capsys):
    motor = tmp_path / "motor.csv"
    log = write_csv(tiny_run(3), motor)
    before = log.read_text()
    assert main(["plan", str(log), "--csv", str(log)]) == 2
    assert "input" in capsys.readouterr().err
    assert log.read_text() == before


def test_the_command_delays_stated_default_is_the_one_used():
    from pmdc_ident.commands import plan
    from pmdc_ident.core.safety import COMMAND_DELAY_S

    parser = argparse.ArgumentParser()
    plan.add_arguments(parser)
    text = parser.format_help()
    assert f"(default {COMMAND_DELAY_S:g} s)" in " ".join(text.split())
