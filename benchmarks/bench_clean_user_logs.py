"""False attribution on effect-free motors logged the way users log them (a table).

Four motors without any effect (8 mW hobby to a 2 kW, 0.12 ohm drive) from the
independent RK4 motor of ``test/helpers/motor_records.py`` (not the package's
simulator), each at 50, 250 and 1000 Hz, as one-direction steps without labels
and as a bidirectional PRBS, position from a 4096-count encoder dropped and only a
noisy speed logged. Each CSV is diagnosed from the file alone; every verdict
other than ``no_gap`` is a false attribution (or a refusal, shown with its line).

Run: ``.venv/bin/python benchmarks/bench_clean_user_logs.py [--out DIR]``
(about 3 min of CPU).
"""

from __future__ import annotations

import argparse
import contextlib
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


def _diagnose(path: Path, extra: list[str]) -> str:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(["diagnose", str(path), "--quiet", "--json", "-", *extra])
    if rc != 0:
        return f"exit {rc}: {err.getvalue().strip().splitlines()[-1]}"
    v = json.loads(out.getvalue())["verdict"]
    return v["status"] + (f" ({', '.join(v['effects'])})" if v["effects"] else "")


def main_(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="keep the CSV files here")
    args = ap.parse_args(argv)
    out = args.out or Path(tempfile.mkdtemp(prefix="clean_user_logs_"))
    out.mkdir(parents=True, exist_ok=True)
    wrong = 0
    print("| record | verdict |\n| --- | --- |")
    for name, (m, vmax) in MOTORS.items():
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
                verdict = _diagnose(path, ["--current-unit", "A"] if name == "big" else [])
                wrong += verdict != "no_gap"
                print(f"| {path.name} | {verdict} |", flush=True)
    n = len(MOTORS) * len(RATES) * 2
    print(f"\nnot no_gap: {wrong} of {n} effect-free records (files in {out})")
    return 0


if __name__ == "__main__":
    sys.exit(main_())
