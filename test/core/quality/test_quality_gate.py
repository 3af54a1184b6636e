"""The data-quality gate (`pmdc-ident check`, and before every fit): one record per slip.

Records come from an independent RK4 integration (``motor_records``), not from the
package's simulator, plus seed 000's tables and a session synthesised by the
package (no false alarm on either). Each slip must give its own error line with
the fix, exit status 2, and pass once the fix is applied.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers.motor_records import Motor, Record, filtered_current, simulate, steps, write_csv
from helpers.paths import FIXTURES

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.quality import GateInput, Severity, check_inputs
from pmdc_ident.dataio.units import load_input

FIX = FIXTURES
CPR = 2048


@pytest.fixture(scope="module")
def base() -> Record:
    """Steps 6 V, 12 V, open (coast), -6 V, 0 V at 1 kHz; noise and a 2048-count encoder."""
    v = steps([6, 12, None, -6, 0], 0.4, 1000)
    return simulate(
        Motor(Tc=0.002), v, 1000, noise_current=0.005, noise_speed=0.05, counts_per_rev=CPR
    )


def check(path: Path, *opts: str, capsys) -> tuple[int, str]:
    rc = main(["check", str(path), *opts])
    cap = capsys.readouterr()
    return rc, cap.out + cap.err


def errors(text: str) -> list[str]:
    return [ln.strip() for ln in text.splitlines() if ln.strip().startswith("error: ")]


def warnings(text: str) -> list[str]:
    return [ln.strip() for ln in text.splitlines() if ln.strip().startswith("warning: ")]


def test_clean_record_passes_with_measurements(base, tmp_path, capsys):
    rc, out = check(write_csv(tmp_path / "clean.csv", base), capsys=capsys)
    assert rc == 0, out
    assert not errors(out) and not warnings(out)
    assert "sample period 1 ms (1000 Hz)" in out
    assert f"an encoder of {CPR} counts/rev" in out
    assert "speed = 1.0000 x d(position)/dt" in out
    assert "the current responds one sample after each of" in out


@pytest.mark.parametrize(
    ("scale", "code", "fix", "option"),
    [
        ({"speed": 30 / math.pi}, "speed-position", "--speed-unit rpm", ["--speed-unit", "rpm"]),
        (
            {"speed": 180 / math.pi},
            "speed-position",
            "--speed-unit deg/s",
            ["--speed-unit", "deg/s"],
        ),
        (
            {"position": 180 / math.pi},
            "speed-position",
            "--position-unit deg",
            ["--position-unit", "deg"],
        ),
        (
            {"position": CPR / (2 * math.pi)},
            "speed-position",
            f"--position-unit counts --counts-per-rev {CPR}",
            ["--position-unit", "counts", "--counts-per-rev", str(CPR)],
        ),
        ({"t": 1e3}, "time-unit", "--time-unit ms", ["--time-unit", "ms"]),
        ({"t": 1e9}, "time-unit", "--time-unit ns", ["--time-unit", "ns"]),
        ({"current": 1e3}, "current-unit", "--current-unit mA", ["--current-unit", "mA"]),
        ({"voltage": 1e3}, "voltage-unit", "--voltage-unit mV", ["--voltage-unit", "mV"]),
        ({"current": -1.0}, "sign", "--column current=-HEADER", ["--column", "current=-current"]),
        (
            {"speed": -1.0, "position": -1.0},
            "sign",
            "--column speed=-HEADER",
            ["--column", "speed=-speed", "--column", "position=-position"],
        ),
    ],
    ids=[
        "rpm",
        "deg/s",
        "position-deg",
        "position-counts",
        "ms",
        "ns",
        "mA",
        "mV",
        "i-sign",
        "w-sign",
    ],
)
def test_unit_slip_is_an_error_with_its_fix_and_the_fix_passes(
    base, tmp_path, capsys, scale, code, fix, option
):
    path = write_csv(tmp_path / "slip.csv", base, scale=scale)
    rc, out = check(path, capsys=capsys)
    assert rc == EXIT_USER_ERROR, out
    lines = [ln for ln in errors(out) if ln.startswith(f"error: {code}:")]
    assert lines, out
    assert f"fix: {fix}" in lines[0] or f"or {fix}" in lines[0], lines[0]
    assert "nothing was fitted" in out
    rc, out = check(path, *option, capsys=capsys)
    assert rc == 0, out
    assert not errors(out) and not warnings(out), out


def test_identify_stops_before_the_fit_on_a_slip(base, tmp_path, capsys):
    path = write_csv(tmp_path / "rpm.csv", base, scale={"speed": 30 / math.pi})
    js = tmp_path / "r.json"
    rc = main(["identify", str(path), "--json", str(js), "--quiet"])
    out = capsys.readouterr()
    assert rc == EXIT_USER_ERROR
    assert "error: speed-position" in out.out and "--speed-unit rpm" in out.out
    assert "nothing was fitted" in out.err and "speed-position" in out.err
    assert not js.exists()


def test_wrapped_position_without_speed_is_unwrapped_and_noted(base, tmp_path, capsys):
    wrapped = replace(base, position=np.mod(base.position, 2 * math.pi))
    path = write_csv(tmp_path / "wrap.csv", wrapped, drop=("speed",))
    rc, out = check(path, capsys=capsys)
    assert rc == 0, out
    assert "position wraps at 2 pi in segment 'run'" in out and "unwrapped" in out
    run = load_input(path).run
    assert np.ptp(run.segments[0].position) > 20 * math.pi


def test_position_wrapping_in_degrees_is_an_error(base, tmp_path, capsys):
    wrapped = replace(base, position=np.mod(np.degrees(base.position), 360.0))
    rc, out = check(write_csv(tmp_path / "wrap.csv", wrapped, drop=("speed",)), capsys=capsys)
    assert rc == EXIT_USER_ERROR
    assert any("position-wrap" in ln and "--position-unit deg" in ln for ln in errors(out)), out


def test_empty_voltage_column_and_zero_current_are_errors(base, tmp_path, capsys):
    empty = replace(base, voltage=np.full_like(base.voltage, np.nan))
    rc, out = check(write_csv(tmp_path / "nov.csv", empty), capsys=capsys)
    assert rc == EXIT_USER_ERROR
    assert any(ln.startswith("error: no-drive:") for ln in errors(out)), out
    zero = replace(base, current=np.zeros_like(base.current))
    path = write_csv(tmp_path / "noi.csv", zero)
    rc, out = check(path, capsys=capsys)
    assert rc == EXIT_USER_ERROR
    assert any("current-missing" in ln and "--column current=none" in ln for ln in errors(out))
    rc, out = check(path, "--column", "current=none", capsys=capsys)
    assert rc == 0, out


def test_same_recording_twice_is_an_error(base, tmp_path, capsys):
    a = write_csv(tmp_path / "a.csv", base)
    b = write_csv(tmp_path / "b.csv", replace(base, t=base.t + 100.0))
    rc = main(["check", str(a), str(b)])
    out = capsys.readouterr().out
    assert rc == EXIT_USER_ERROR
    assert "error: duplicate: " in out and "holds the same samples as" in out
    rc = main(["check", str(a), str(a)])
    assert "passed twice" in capsys.readouterr().out


def test_gaps_jitter_clipping_and_delay_are_warnings(base, tmp_path):
    rng = np.random.default_rng(3)
    keep = np.ones(base.t.size, dtype=bool)
    keep[500:540] = False
    gappy = Record(
        *(a[keep] for a in (base.t, base.voltage, base.current, base.speed)), base.position[keep]
    )
    jitter = replace(base, t=base.t + rng.uniform(-2e-4, 2e-4, base.t.size))
    clipped = replace(base, current=np.minimum(base.current, 0.8 * base.current.max()))
    delayed = replace(base, voltage=np.concatenate([base.voltage[2:], base.voltage[-2:]]))
    for name, rec, code in (
        ("gap", gappy, "gaps"),
        ("jitter", jitter, "jitter"),
        ("clip", clipped, "clipping"),
        ("delay", delayed, "delay"),
    ):
        x = load_input(write_csv(tmp_path / f"{name}.csv", rec))
        report = check_inputs([GateInput(x.path, x.run, notes=x.notes)])
        found = [f for f in report.findings if f.code == code]
        assert found and found[0].severity is Severity.WARNING, (name, report.lines())
        assert not report.errors, (name, report.lines())
    x = load_input(tmp_path / "delay.csv")
    lag = next(f for f in check_inputs([GateInput(x.path, x.run)]).findings if f.code == "delay")
    assert lag.value == 2.0
    assert "shift the voltage column 2 sample(s) later" in lag.line()


@pytest.mark.parametrize("position", ["held", "restarted"])
def test_a_gap_while_the_motor_turns_refuses_nothing_the_gap_alone_breaks(
    base, tmp_path, position
):
    """A board that resets mid-run (the emulated Uno's AVR reset): 250 samples missing
    while the rotor turns at 12 V, and the encoder's count lost over them. The serial
    backend holds the position at its last value across the re-handshake (speed 0 on the
    first sample of the new stream); a logger of the raw count restarts it at 0. Either
    way speed and d(position)/dt disagree only across the gap, which nobody observed:
    the gate says 'gaps' and refuses nothing (it used to read speed = 33 x
    d(position)/dt there and ask for --speed-unit counts/s)."""
    keep = np.ones(base.t.size, dtype=bool)
    keep[500:750] = False
    pos = base.position.copy()
    speed = base.speed.copy()
    if position == "held":
        pos[750:] -= pos[750] - pos[499]
        speed[750] = 0.0
    else:
        pos[750:] -= pos[750]
    rec = Record(base.t[keep], base.voltage[keep], base.current[keep], speed[keep], pos[keep])
    x = load_input(write_csv(tmp_path / f"reset_{position}.csv", rec))
    report = check_inputs([GateInput(x.path, x.run, notes=x.notes)])
    assert not report.errors, report.lines()
    assert [f.code for f in report.findings if f.code == "gaps"] == ["gaps"]
    ratio = next(f for f in report.findings if f.code == "speed-position")
    assert ratio.value == pytest.approx(1.0, abs=0.01)  # read on the pieces between


def test_no_false_alarm_on_seed000_tables(capsys):
    files = [str(FIX / "seed000_table4.csv"), str(FIX / "seed000_retardation.csv")]
    rc = main(["check", *files])
    out = capsys.readouterr().out
    assert rc == 0
    assert not errors(out) and not warnings(out), out
    assert "info: one-direction" in out and "record both directions" in out


def test_no_false_alarm_on_a_synthesised_session(tmp_path, capsys):
    """The package's own simulator: seed 000's default plan at 1 kHz, demo sensors."""
    from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.dataio.csvio import write_csv as write_run

    spec = load_motor("seed000_ebike")
    run = synthesize_run(spec.model, plan_for_motor(spec, 1e-3), spec.sensors, seed=2)
    js = tmp_path / "q.json"
    rc = main(["check", str(write_run(run, tmp_path / "s.csv")), "--json", str(js)])
    out = capsys.readouterr().out
    assert rc == 0 and not errors(out) and not warnings(out), out
    q = json.loads(js.read_text())["quality"]
    assert q["errors"] == 0 and q["warnings"] == 0
    enc = next(f for f in q["findings"] if f["code"] == "encoder")
    assert enc["value"] == pytest.approx(4096, rel=1e-6)


def test_ignore_takes_only_known_codes_and_turns_the_error_into_a_warning(base, tmp_path, capsys):
    path = write_csv(tmp_path / "ms.csv", base, scale={"t": 1e3})
    assert main(["check", str(path), "--ignore", "nosuch"]) == EXIT_USER_ERROR
    err = capsys.readouterr().err
    assert "--ignore nosuch: not a finding code (codes: check-failed, clipping," in err
    assert err.count("\n") == 1
    rc, out = check(path, "--ignore", "time-unit", capsys=capsys)
    assert rc == 0
    assert "warning: time-unit:" in out and "(ignored by the user)" in out


def test_voltage_and_speed_without_current_says_what_it_can_tell(base, tmp_path, capsys):
    rc, out = check(write_csv(tmp_path / "nocur.csv", base, drop=("current",)), capsys=capsys)
    assert rc == 0
    line = next(ln for ln in warnings(out) if ln.startswith("warning: no-current:"))
    # Motor(): gain Ke/(R B + Ke^2) = 19.97 rad/s per V
    assert "shows a gain of 19." in line or "shows a gain of 20." in line, line
    assert "record the armature current" in line


def test_an_analog_filter_on_the_current_sensor_is_a_warning(tmp_path):
    """2 ms RC before the ADC (L/R = 1 ms, 1 kHz): the current rises S-shaped."""
    v = steps([6, 12, None, -6, 0], 0.4, 1000)
    rec = filtered_current(Motor(Tc=0.002), v, 1000, 2e-3)
    x = load_input(write_csv(tmp_path / "rc.csv", rec))
    found = [
        f for f in check_inputs([GateInput(x.path, x.run)]).findings if f.code == "current-filter"
    ]
    assert found and found[0].severity is Severity.WARNING
    assert found[0].value > 1.2
    # the same motor with an unfiltered sensor: no such finding (see the clean test too)
    raw = simulate(Motor(Tc=0.002), np.repeat(v, 20), 20000, substeps=1).current[::20]
    y = load_input(write_csv(tmp_path / "raw.csv", replace(rec, current=raw)))
    assert not [
        f for f in check_inputs([GateInput(y.path, y.run)]).findings if f.code == "current-filter"
    ]
