"""Record shapes and unit slips of issue 9: what `pmdc-ident` makes of each (a table).

Each record comes from the independent RK4 motor of ``test/helpers/motor_records.py`` (not
the package's simulator) and is written under ``--out DIR`` (default a temporary
folder), so every row's command can be re-run by hand. For a shape that should
identify, the row gives the largest error of R, Ke, J (and L where the record
resolves it) against the truth; for a slip, the gate's first error line.

Run: ``.venv/bin/python benchmarks/bench_record_shapes.py [--out DIR]``.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import sys
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from helpers.motor_records import (  # noqa: E402
    Motor,
    Record,
    continuous_voltage,
    filtered_current,
    prbs,
    simulate,
    speed_pi,
    steps,
    write_csv,
)

from pmdc_ident.cli import main  # noqa: E402

BASE = Motor(Tc=0.002)  # R 2, L 2 mH, Ke = Kt 0.05, J 2e-5, B 2e-6, Tc 2 mN*m


def _run(argv: list[str]) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue() + err.getvalue()


def _fit(path: Path, truth: Motor, extra: list[str], names: tuple[str, ...]) -> str:
    js = path.with_suffix(".json")
    rc, text = _run(["identify", str(path), "--quiet", "--json", str(js), *extra])
    if rc != 0:
        return f"exit {rc}: {text.strip().splitlines()[-1]}"
    params = json.loads(js.read_text())["parameters"]
    errs = {n: params[n]["value"] / getattr(truth, n) - 1.0 for n in names}
    worst = max(errs, key=lambda n: abs(errs[n]))
    flags = [n for n in ("R", "L", "J") if not params[n]["identifiable"]]
    note = f"; flagged not identifiable: {', '.join(flags)}" if flags else ""
    listed = ", ".join(f"{n} {100 * e:+.2f} %" for n, e in errs.items())
    return f"exit 0; {listed} (worst {worst}){note}"


def _check(path: Path, extra: list[str]) -> str:
    rc, text = _run(["check", str(path), *extra])
    lines = [ln.strip() for ln in text.splitlines() if ln.strip().startswith(("error:", "warn"))]
    first = lines[0] if lines else text.strip().splitlines()[-1]
    return f"exit {rc}; {first[:240]}"


def _cases(out: Path) -> list[tuple[str, Callable[[], tuple[str, str]]]]:
    v_steps = steps([6, 12, None, -6, 0], 0.4, 1000)
    base = simulate(
        BASE, v_steps, 1000, noise_current=0.005, noise_speed=0.05, counts_per_rev=2048
    )

    epoch = replace(base, t=base.t + 1.7e9)  # Unix time in s (x 1e3: in ms)

    def identify(name: str, rec: Record, truth: Motor, names=("R", "Ke", "J"), extra=(), **kw):
        path = write_csv(out / f"{name}.csv", rec, **kw)
        cmd = " ".join(["pmdc-ident identify", str(path), *extra])
        return _fit(path, truth, list(extra), names), cmd

    def check(name: str, rec: Record, extra=(), **kw):
        path = write_csv(out / f"{name}.csv", rec, **kw)
        return _check(path, list(extra)), " ".join(["pmdc-ident check", str(path), *extra])

    def one_direction():
        v = np.r_[np.zeros(50), np.full(1000, 8.0)]
        m = Motor(R=10.0, L=0.5e-3, Ke=0.07, Kt=0.07, J=5e-6, B=1e-6, Tc=1e-3)
        rec = simulate(m, v, 500, substeps=40, noise_current=0.002, noise_speed=0.05)
        return identify("one_direction_500hz", rec, m, drop=("position",))

    def held_from_first_sample():
        m = Motor(R=10.0, L=0.5e-3, Ke=0.07, Kt=0.07, J=5e-6, B=1e-6, Tc=1e-3)
        rec = simulate(
            m, np.full(1000, 8.0), 500, substeps=40, noise_current=0.002, noise_speed=0.05
        )
        return identify("step_on_at_first_sample", rec, m, drop=("position",))

    def continuous():
        rec = simulate(
            BASE,
            continuous_voltage(1000),
            1000,
            substeps=10,
            noise_current=0.005,
            noise_speed=0.05,
        )
        return identify("continuous_unlabeled", rec, BASE, names=("R", "L", "Ke", "J"))

    def closed_loop():
        ref = np.repeat([100.0, 200.0, -100.0], 1000)
        rec = simulate(
            BASE,
            np.zeros(3000),
            1000,
            substeps=10,
            noise_current=0.005,
            noise_speed=0.2,
            counts_per_rev=1024,
            controller=speed_pi(ref),
        )
        return identify("closed_loop_pi", rec, BASE, names=("R", "L", "Ke", "J"))

    def current_driven():
        rec = simulate(BASE, v_steps, 1000, noise_current=0.005, noise_speed=0.05)
        path = write_csv(out / "current_driven.csv", rec, drop=("voltage", "position"))
        return _fit(path, BASE, ["--fix", "Kt=0.05"], ("J",)), (
            f"pmdc-ident identify {path} --fix Kt=0.05"
        )

    def rate(hz: int, m: Motor, name: str, names, seconds=0.1, sub=4):
        rec = simulate(
            m,
            steps([3, 6, -3, 0], seconds, hz),
            hz,
            substeps=sub,
            noise_current=0.002,
            noise_speed=0.2,
        )
        return identify(name, rec, m, names=names, drop=("position",))

    small = Motor(R=3.5, L=0.49e-3, Ke=0.012, Kt=0.012, J=1e-6, B=1e-8)
    geared = Motor(R=1.1, L=1.0e-3, Ke=0.03, Kt=0.03, J=2e-5, B=1e-6)

    def fifty_hz():
        m = Motor(R=8.0, L=2e-3, Ke=0.008, Kt=0.008, J=2e-7, B=1e-8, Tc=2e-5)
        rec = simulate(m, prbs(1000, 6.0, 1, seed=3), 50, substeps=100, noise_current=0.003)
        # an encoder interface's speed: the counts since the last sample over the period
        q = 2 * math.pi / 12
        rec.speed = np.r_[0.0, np.diff(np.floor(rec.position / q))] * q / 0.02
        path = write_csv(out / "prbs_50hz_counted_speed.csv", rec, drop=("position",))
        res = _check(path, []) + " / with --speed-averaged: "
        res += _fit(path, m, ["--speed-averaged"], ("R", "L", "Ke", "J"))
        return res, f"pmdc-ident identify {path} [--speed-averaged]"

    def encoder_only():
        rec = simulate(BASE, v_steps, 1000, substeps=10, noise_current=0.005, counts_per_rev=256)
        return identify(
            "encoder_256_position_only", rec, BASE, names=("R", "L", "Ke", "J"), drop=("speed",)
        )

    def wrapped():
        rec = replace(base, position=np.mod(base.position, 2 * math.pi))
        return identify("position_wrapped_no_speed", rec, BASE, drop=("speed",))

    def filtered():
        rec = filtered_current(BASE, v_steps, 1000, 2e-3)
        path = write_csv(out / "current_sensor_rc_2ms.csv", rec)
        res = _fit(path, BASE, [], ("R", "L", "Ke", "J")) + " / " + _check(path, [])
        return res, f"pmdc-ident identify {path}"

    def no_current():
        path = write_csv(out / "no_current_column.csv", base, drop=("current", "position"))
        res = _fit(path, BASE, [], ("R", "Ke", "J"))
        fixed = _fit(path, BASE, ["--fix", "R=2"], ("Ke", "J"))
        return f"{res} / with --fix R=2: {fixed}", f"pmdc-ident identify {path} [--fix R=2]"

    def gaps():
        labels = ("step_up", "step_up_2", "coast", "step_down", "step_down_2")
        rec = replace(base, labels=list(np.repeat(labels, 400)))
        keep = np.ones(rec.t.size, dtype=bool)
        keep[450:490] = False
        keep[1500:1503] = False
        cut = Record(
            *(getattr(rec, k)[keep] for k in ("t", "voltage", "current", "speed", "position")),
            labels=[lab for lab, k in zip(rec.labels, keep, strict=True) if k],
        )
        return identify("dropped_samples_43", cut, BASE, names=("R", "L", "Ke", "J"))

    def slip(name: str, scale: dict, undo: tuple[str, ...] = (), rec: Record | None = None):
        """The gate's line on the slipped record; then identify with the option undoing it."""

        def case():
            path = write_csv(out / f"slip_{name}.csv", rec or base, scale=scale)
            caught = _check(path, [])
            cmd = f"pmdc-ident check {path}"
            if undo:
                names = ("R", "L", "Ke", "J")
                caught += f" / with {' '.join(undo)}: {_fit(path, BASE, list(undo), names)}"
                cmd += f"; pmdc-ident identify {path} {' '.join(undo)}"
            return caught, cmd

        return case

    def empty_voltage():
        return check(
            "slip_voltage_empty", replace(base, voltage=np.full_like(base.voltage, np.nan))
        )

    def zero_current():
        return check("slip_current_zero", replace(base, current=np.zeros_like(base.current)))

    def twice():
        path = write_csv(out / "twice.csv", base)
        return _check(path, [str(path)]), f"pmdc-ident check {path} {path}"

    return [
        ("one direction (8 V step from rest, 500 Hz)", one_direction),
        ("step with the voltage on at the first sample", held_from_first_sample),
        ("one continuous unlabeled log (segmented)", continuous),
        ("closed-loop speed control (PI)", closed_loop),
        ("current-driven (no voltage column), J given Kt", current_driven),
        (
            "20 kHz, L/R = 0.14 ms",
            lambda: rate(20000, small, "small_20khz", ("R", "L", "Ke", "J")),
        ),
        ("5 kHz, L/R = 0.14 ms", lambda: rate(5000, small, "small_5khz", ("R", "L", "Ke", "J"))),
        (
            "1 kHz geared, L/R = 0.9 ms",
            lambda: rate(1000, geared, "geared_1khz", ("R", "L", "Ke", "J"), 0.5, 10),
        ),
        ("50 Hz PRBS, speed = 12-count encoder counts per sample", fifty_hz),
        ("256-count encoder, no speed column", encoder_only),
        ("position wrapped to [0, 2 pi), no speed column", wrapped),
        ("current sensor behind a 2 ms RC filter", filtered),
        ("voltage and speed, no current column", no_current),
        ("43 dropped samples (gaps in 2 segments)", gaps),
        ("slip: speed in rpm", slip("rpm", {"speed": 30 / math.pi}, ("--speed-unit", "rpm"))),
        (
            "slip: speed in deg/s",
            slip("degs", {"speed": 180 / math.pi}, ("--speed-unit", "deg/s")),
        ),
        (
            "slip: position in deg",
            slip("posdeg", {"position": 180 / math.pi}, ("--position-unit", "deg")),
        ),
        (
            "slip: position in counts",
            slip(
                "counts",
                {"position": 2048 / (2 * math.pi)},
                ("--position-unit", "counts", "--counts-per-rev", "2048"),
            ),
        ),
        ("slip: time in ms", slip("ms", {"t": 1e3}, ("--time-unit", "ms"))),
        ("slip: time in us", slip("us", {"t": 1e6}, ("--time-unit", "us"))),
        ("slip: time in ns", slip("ns", {"t": 1e9}, ("--time-unit", "ns"))),
        (
            "slip: epoch time in ms",
            slip("epoch_ms", {"t": 1e3}, ("--time-unit", "ms"), rec=epoch),
        ),
        ("slip: current in mA", slip("mA", {"current": 1e3}, ("--current-unit", "mA"))),
        ("slip: voltage in mV", slip("mV", {"voltage": 1e3}, ("--voltage-unit", "mV"))),
        (
            "slip: voltage logged as duty % of a 24 V supply",
            slip("duty", {"voltage": 100 / 24}, ("--voltage-unit", "duty%", "--supply-v", "24")),
        ),
        (
            "slip: speed and position on the load side of a 10:1 gear",
            slip("gear", {"speed": 0.1, "position": 0.1}, ("--gear-ratio", "10")),
        ),
        (
            "slip: current wires swapped",
            slip("isign", {"current": -1.0}, ("--column", "current=-current")),
        ),
        ("slip: voltage column all empty", empty_voltage),
        ("slip: current all zero", zero_current),
        ("slip: the same file twice", twice),
    ]


def main_() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="keep the records here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        print("| record shape or slip | outcome | command |")
        print("| --- | --- | --- |")
        for name, case in _cases(out):
            outcome, cmd = case()
            print(f"| {name} | {outcome.replace('|', '/')} | `{cmd}` |", flush=True)


if __name__ == "__main__":
    main_()
