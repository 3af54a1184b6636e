"""What a user waits for: cold and warm wall + CPU time of whole ``pmdc-ident`` commands.

    .venv/bin/python benchmarks/bench_cli.py [--repeat 3] [--skip-diagnose] [--bag PATH]

Each figure is a fresh ``pmdc-ident`` process (start-up, imports, reading the data,
the fit, the report), timed from outside: wall time and the child's user + system
CPU time. *Cold* runs get an empty numba cache directory (``NUMBA_CACHE_DIR``, so
every kernel is compiled); *warm* runs reuse the directory a first run filled. The
commands: ``--help``, an argument error, ``identify`` and ``diagnose`` on a 60 s,
1 kHz simulated run (the seed-000 e-bike motor with its Coulomb friction, all four
test types, written as an MCAP bag) and on the 39.8 s default sequence of the same
motor (``make demo``'s; ``--bag PATH`` times a recorded bag instead, e.g.
``pmdc_sessions/demo/<session>``). Every figure is the median of ``--repeat`` runs
(min-max in brackets); the load average is printed before and after, since the
machine is shared and wall time depends on it while CPU time much less so.
"""

from __future__ import annotations

import argparse
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

EXE = Path(sys.executable).with_name("pmdc-ident")


def _timed(cmd: list[str], env: dict[str, str]) -> tuple[float, float, int]:
    """Wall and CPU (user + system) time of one child process, and its exit status."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    if proc.returncode not in (0, 2):
        print(f"  ! {' '.join(cmd[1:])}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
    return wall, cpu, proc.returncode


def _fmt(values: list[float]) -> str:
    med = statistics.median(values)
    if len(values) == 1:
        return f"{med:7.2f}"
    return f"{med:7.2f} [{min(values):.2f}-{max(values):.2f}]"


def measure(name: str, args: list[str], repeat: int, scratch: Path) -> None:
    """Cold (fresh numba cache) and warm (second use of that cache) runs of one command."""
    rows: dict[str, tuple[list[float], list[float]]] = {"cold": ([], []), "warm": ([], [])}
    for _ in range(repeat):
        cache = Path(tempfile.mkdtemp(prefix="numba_cache_", dir=scratch))
        env = {**os.environ, "NUMBA_CACHE_DIR": str(cache)}
        for mode in ("cold", "warm"):
            wall, cpu, _rc = _timed([str(EXE), *args], env)
            rows[mode][0].append(wall)
            rows[mode][1].append(cpu)
    for mode, (walls, cpus) in rows.items():
        print(f"  {name:<28} {mode}  wall {_fmt(walls)} s   CPU {_fmt(cpus)} s", flush=True)


def make_runs(scratch: Path) -> dict[str, Path]:
    """The simulated runs as MCAP bags: 60 s and the 39.8 s default sequence, 1 kHz."""
    from bench_identify_speed import DT_S, plan_60s

    from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.dataio.bagio import write_bag

    spec = load_motor("seed000_ebike")
    out = {}
    for label, plan in (
        ("60 s", plan_60s(spec)[0]),
        ("39.8 s", plan_for_motor(spec, DT_S)),
    ):
        run = synthesize_run(spec.model, plan, spec.sensors, seed=1)
        path = scratch / f"run_{plan.duration_s:.0f}s"
        write_bag(run, path)
        out[f"{label} ({plan.duration_s:.1f} s, 1 kHz)"] = path
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=3, help="runs per figure (median reported)")
    ap.add_argument("--skip-diagnose", action="store_true", help="skip the slow diagnose runs")
    ap.add_argument("--bag", action="append", default=[], help="also time this recorded bag")
    args = ap.parse_args(argv)
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{os.cpu_count()} CPUs; {args.repeat} runs per figure, median [min-max]")
    with tempfile.TemporaryDirectory(prefix="bench_cli_") as tmp:
        scratch = Path(tmp)
        runs = make_runs(scratch)
        runs.update({f"bag {Path(b).name}": Path(b) for b in args.bag})
        print("== pmdc-ident start-up")
        measure("--help", ["--help"], args.repeat, scratch)
        measure("identify (argument error)", ["identify", "--bootstrap"], args.repeat, scratch)
        for label, path in runs.items():
            print(f"== {label}: {path.name}")
            measure("identify", ["identify", str(path), "--quiet"], args.repeat, scratch)
            if not args.skip_diagnose:
                measure("diagnose", ["diagnose", str(path)], args.repeat, scratch)
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
