"""Effect-free motors logged the way users log them, or with one effect (a table).

Four motors without any effect (8 mW hobby to a 2 kW, 0.12 ohm drive) from the
independent RK4 motor of ``test/helpers/motor_records.py`` (not the package's
simulator), each at 50, 250 and 1000 Hz, as one-direction steps without labels
and as a bidirectional PRBS, position from a 4096-count encoder dropped and only a
noisy speed logged. Each CSV is diagnosed from the file alone; every verdict
other than ``no_gap`` is a false attribution (or a refusal, shown with its line).

``--effect coulomb`` or ``--effect load`` gives every motor a Coulomb friction or a
constant load torque of 5 % of its stall torque (the RK4 motor's own sign law with
stiction, not the candidate's equation); a record is then right when the effect is
named first or tied with the first name. A bidirectional PRBS that holds the speed
near +-max most of the time lets the linear model's B absorb a Coulomb friction
(B w is then a sign law too): ``no_gap`` is an honest answer there, counted apart.

Run: ``.venv/bin/python benchmarks/bench_clean_user_logs.py [--effect E] [--out DIR]``
(about 3 min of CPU each).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))

from helpers.motor_records import Motor, prbs, simulate, steps, write_csv  # noqa: E402

from pmdc_ident.cli import main  # noqa: E402

# name: (motor, top voltage)
MOTORS: dict[str, tuple[Motor, float]] = {
    "tiny": (Motor(R=8.0, L=0.4e-3, Ke=0.008, Kt=0.008, J=2e-7, B=1e-8), 6.0),
    "mid": (Motor(R=2.0, L=2e-3, Ke=0.05, Kt=0.05, J=2e-5, B=2e-6), 12.0),
    "geared": (Motor(R=1.1, L=1e-3, Ke=0.03, Kt=0.03, J=2e-5, B=1e-6), 12.0),
    "big": (Motor(R=0.12, L=0.15e-3, Ke=0.25, Kt=0.25, J=4e-3, B=2e-4), 48.0),
}
RATES = (50, 250, 1000)
# --effect: the Motor field set to 5 % of the stall torque, and the names that count
EFFECTS: dict[str, tuple[str, tuple[str, ...]]] = {
    "none": ("", ("no_gap",)),
    "coulomb": ("Tc", ("coulomb_friction",)),
    "load": ("T_load", ("load_torque",)),
}
EFFECT_SHARE = 0.05


def _diagnose(path: Path, extra: list[str]) -> tuple[str, set[str]]:
    """The verdict as a line, and the names it puts first (the first effect and
    what is tied with it, or the status when none is named)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["diagnose", str(path), "--quiet", "--json", "-", *extra])
    if rc != 0:
        return f"exit {rc}: {err.getvalue().strip().splitlines()[-1]}", set()
    v = json.loads(out.getvalue())["verdict"]
    if not v["effects"]:
        return v["status"], {v["status"]}
    first = v["effects"][0]
    tied = {n for t in v["ties"] if t["effects"][0] == first for n in t["effects"]}
    line = f"{v['status']} ({', '.join(v['effects'])})"
    if tied:
        line += f", tied: {', '.join(sorted(tied - {first}))}"
    return line, {first} | tied


def main_(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="keep the CSV files here")
    ap.add_argument("--effect", choices=sorted(EFFECTS), default="none")
    args = ap.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="clean_user_logs_"))
    out.mkdir(parents=True, exist_ok=True)
    field, right = EFFECTS[args.effect]
    wrong = 0
    print("| record | verdict |\n| --- | --- |")
    for name, (m0, vmax) in MOTORS.items():
        stall = m0.Kt * vmax / m0.R
        m = dataclasses.replace(m0, **{field: EFFECT_SHARE * stall}) if field else m0
        for rate in RATES:
            shapes = {
                "onedir": steps([0, 0.5 * vmax, vmax, 0.25 * vmax, 0.75 * vmax, 0], 1.0, rate),
                "prbs": prbs(6 * rate, 0.7 * vmax, max(1, rate // 25), seed=3),
            }
            for shape, v in shapes.items():
                rec = simulate(
                    m,
                    v,
                    rate,
                    substeps=min(200, max(4, 20000 // rate)) if rate < 1000 else 20,
                    noise_current=0.003 * vmax / m.R * 0.05,
                    noise_speed=0.002 * vmax / m.Ke,
                    counts_per_rev=4096,
                    seed=7,
                )
                path = write_csv(out / f"{name}_{rate}_{shape}.csv", rec, drop=("position",))
                # a 2 kW drive without a current limit draws hundreds of amperes: say A
                verdict, first = _diagnose(path, ["--current-unit", "A"] if name == "big" else [])
                wrong += not first & set(right)
                print(f"| {path.name} | {verdict} |", flush=True)
    n = len(MOTORS) * len(RATES) * 2
    what = "effect-free" if not field else f"{args.effect} ({EFFECT_SHARE:.0%} of stall torque)"
    print(f"\nnot {' or '.join(right)} first: {wrong} of {n} {what} records (files in {out})")
    return 0


if __name__ == "__main__":
    sys.exit(main_())
