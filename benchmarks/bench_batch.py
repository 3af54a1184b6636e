"""Batch re-identification throughput: runs per minute for a folder of session bags.

    .venv/bin/python benchmarks/bench_batch.py [--runs 100] [--jobs 2] [--naive 10] [--keep DIR]

Generates ``--runs`` demo-sized session bags (the 39.8 s default sequence of the
seed-000 e-bike motor at 1 kHz, each with its own noise seed, written as MCAP bags
like the recorder's) and times ``pmdc-ident identify --batch OUT --jobs N DIR`` on
them: wall time, runs per minute and the workers' CPU time (as the batch reports it).
The naive reference in the same run is what a user would script: one
``pmdc-ident identify BAG --json OUT`` process per bag, one after the other, timed
on the first ``--naive`` bags (per-run figures scale). Every batch JSON is checked
against the truth (R within 0.1 %). ``--keep DIR`` keeps (and reuses) the bags.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

EXE = Path(sys.executable).with_name("pmdc-ident")


def make_bags(folder: Path, n: int) -> list[Path]:
    from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.dataio.bagio import write_bag

    spec = load_motor("seed000_ebike")
    plan = plan_for_motor(spec, 1e-3)
    folder.mkdir(parents=True, exist_ok=True)
    bags = []
    t0 = time.perf_counter()
    for k in range(n):
        bag = folder / f"session_{k:03d}"
        if not (bag / "metadata.yaml").is_file():
            write_bag(synthesize_run(spec.model, plan, spec.sensors, seed=100 + k), bag)
        bags.append(bag)
    took = time.perf_counter() - t0
    print(f"{n} bags of {plan.duration_s:.1f} s at 1 kHz in {folder} (made in {took:.0f} s)")
    return bags


def timed(cmd: list[str]) -> tuple[float, float, int, str]:
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return wall, cpu, proc.returncode, proc.stdout + proc.stderr


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--naive", type=int, default=10, help="bags timed one process each")
    ap.add_argument("--keep", help="keep the generated bags in this folder (reused)")
    args = ap.parse_args(argv)
    print(
        f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}; "
        f"{os.cpu_count()} CPUs"
    )
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        folder = Path(args.keep) if args.keep else Path(tmp) / "bags"
        bags = make_bags(folder, args.runs)
        out = Path(tmp) / "batch_out"
        wall, _cpu, rc, text = timed(
            [
                str(EXE),
                "identify",
                "--batch",
                str(out),
                "--jobs",
                str(args.jobs),
                "--quiet",
                *map(str, bags),
            ]
        )
        done = sorted(out.glob("*.json"))
        r_err = (
            max(
                abs(json.loads(p.read_text())["parameters"]["R"]["value"] / 1.375 - 1)
                for p in done
            )
            if done
            else float("nan")
        )
        print(
            f"batch: {len(done)}/{len(bags)} identified (exit {rc}) in {wall:.1f} s wall with "
            f"--jobs {args.jobs}: {60 * len(bags) / wall:.1f} runs per minute "
            f"({wall / len(bags):.2f} s wall per run); max |R error| {r_err:.2e}"
        )
        print(
            "  the batch says: "
            + next((line for line in text.splitlines() if " inputs done in " in line), "?")
        )
        if rc != 0:
            print(text[-3000:])
        n = min(args.naive, len(bags))
        if n:
            nw = nc = 0.0
            for k, bag in enumerate(bags[:n]):
                w, c, _rc, _ = timed(
                    [
                        str(EXE),
                        "identify",
                        str(bag),
                        "--quiet",
                        "--json",
                        str(Path(tmp) / f"naive_{k}.json"),
                    ]
                )
                nw, nc = nw + w, nc + c
            print(
                f"naive (one process per bag, in sequence), first {n} bags: {nw / n:.2f} s wall, "
                f"{nc / n:.2f} s CPU per run: {60 * n / nw:.1f} runs per minute; batch is "
                f"x{(nw / n) / (wall / len(bags)):.1f} the throughput"
            )
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
