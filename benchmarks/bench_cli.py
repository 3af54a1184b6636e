"""What a user waits for: cold and warm wall + CPU time of whole ``pmdc-ident`` commands.

    .venv/bin/python benchmarks/bench_cli.py [--repeat 3] [--skip-diagnose] [--skip-node]
        [--bag PATH] [--no-bytecode-cache]

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

Python's own bytecode cache (``__pycache__``) is part of a warm start too: the children
run without ``PYTHONDONTWRITEBYTECODE`` (a user's default; some sandboxes set it, and
then every module of the package is compiled from source in every process, ~0.08 s),
unless ``--no-bytecode-cache``.

The identification node's start: ``identification_node`` launched (``autostart`` off, a
DDS domain of its own), seconds until its log says it is ready (its status published)
and until another node receives that status (DDS discovery included).

Naive references in the same run: ``--help`` against a process importing every command
module and the estimators up front (the pre-lazy-import start-up), ``identify`` and
``diagnose`` warm against cold (every kernel compiled, as without the on-disk cache),
the node against the same node importing numba before it starts (as before numba was
imported at the first kernel call). The last lines are issue 14's goals.
"""

from __future__ import annotations

import argparse
import os
import re
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
    """Wall and CPU (user + system) time of one child process, and its exit status
    (its standard error is kept in ``_timed.stderr``)."""
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    _timed.stderr = proc.stderr  # type: ignore[attr-defined]
    if proc.returncode not in (0, 2):
        print(f"  ! {' '.join(cmd[1:])}: exit {proc.returncode}\n{proc.stderr[-2000:]}")
    return wall, cpu, proc.returncode


def _fmt(values: list[float]) -> str:
    med = statistics.median(values)
    if len(values) == 1:
        return f"{med:7.2f}"
    return f"{med:7.2f} [{min(values):.2f}-{max(values):.2f}]"


# The naive reference for start-up: the same help text from a process that imports every
# command module and the estimators they use up front (what --help cost before the imports
# were made lazy).
EAGER_HELP = (
    "import pmdc_ident.cli as cli\n"
    "for m in cli.COMMANDS.values():\n"
    "    __import__('pmdc_ident.commands.' + m)\n"
    "import pmdc_ident.core.identification.identify, pmdc_ident.core.diagnosis.pipeline\n"
    "import pmdc_ident.dataio.bagio, pmdc_ident.report.plots\n"
    "cli.main(['--help'])\n"
)


def _child_env(**extra: str) -> dict[str, str]:
    env = {**os.environ, **extra}
    if not _child_env.no_bytecode_cache:  # type: ignore[attr-defined]
        env.pop("PYTHONDONTWRITEBYTECODE", None)
    return env


_child_env.no_bytecode_cache = False  # type: ignore[attr-defined]


def measure(
    name: str, args: list[str], repeat: int, scratch: Path, fits: bool = False
) -> dict[str, tuple[list[float], list[float]]]:
    """Cold (fresh numba cache) and warm (second use of that cache) runs of one command.

    With ``fits=True`` (``identify`` with its progress lines) the warm runs' time from
    the start of the linear output-error fit to the end of the Coulomb fit and the
    model choice (the progress stamps of 'output error, linear model' and 'validation')
    is printed too."""
    rows: dict[str, tuple[list[float], list[float]]] = {"cold": ([], []), "warm": ([], [])}
    fit_s: list[float] = []
    for _ in range(repeat):
        cache = Path(tempfile.mkdtemp(prefix="numba_cache_", dir=scratch))
        env = _child_env(NUMBA_CACHE_DIR=str(cache))
        for mode in ("cold", "warm"):
            wall, cpu, _rc = _timed([str(EXE), *args], env)
            rows[mode][0].append(wall)
            rows[mode][1].append(cpu)
            if mode == "warm" and fits:
                fit_s.extend(_fit_span(_timed.stderr))  # type: ignore[attr-defined]
    for mode, (walls, cpus) in rows.items():
        print(f"  {name:<28} {mode}  wall {_fmt(walls)} s   CPU {_fmt(cpus)} s", flush=True)
    if fit_s:
        print(f"  {'  of it linear+Coulomb fits':<28} warm  wall {_fmt(fit_s)} s")
    return rows


_STAMP = re.compile(r"^\[\s*([0-9.]+) s\] (output error, linear model|validation)")


def _fit_span(stderr: str) -> list[float]:
    """Seconds from 'output error, linear model' to 'validation' in identify's progress."""
    t = {m.group(2): float(m.group(1)) for m in map(_STAMP.match, stderr.splitlines()) if m}
    if len(t) < 2:
        return []
    return [t["validation"] - t["output error, linear model"]]


def _ratio(name: str, ref: list[float], ours: list[float], what: str) -> None:
    r = statistics.median(ref) / statistics.median(ours)
    print(f"  {name:<28} ratio {r:5.1f}x  ({what})", flush=True)


def measure_eager_help(repeat: int) -> list[float]:
    """Wall times of the eager-import reference of ``--help``."""
    walls, cpus = [], []
    for _ in range(repeat):
        wall, cpu, _rc = _timed([sys.executable, "-c", EAGER_HELP], _child_env())
        walls.append(wall)
        cpus.append(cpu)
    print(
        f"  {'--help, eager imports':<28} ref   wall {_fmt(walls)} s   CPU {_fmt(cpus)} s",
        flush=True,
    )
    return walls


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
    ap.add_argument("--skip-node", action="store_true", help="skip the node start-up runs")
    ap.add_argument("--bag", action="append", default=[], help="also time this recorded bag")
    ap.add_argument(
        "--no-bytecode-cache",
        action="store_true",
        help="keep PYTHONDONTWRITEBYTECODE from the environment (modules compiled each run)",
    )
    args = ap.parse_args(argv)
    _child_env.no_bytecode_cache = args.no_bytecode_cache  # type: ignore[attr-defined]
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{os.cpu_count()} CPUs; {args.repeat} runs per figure, median [min-max]")
    cached = "off (--no-bytecode-cache)" if args.no_bytecode_cache else "on"
    print(f"Python bytecode cache in the children: {cached}")
    goals: list[str] = []
    with tempfile.TemporaryDirectory(prefix="bench_cli_") as tmp:
        scratch = Path(tmp)
        runs = make_runs(scratch)
        runs.update({f"bag {Path(b).name}": Path(b) for b in args.bag})
        print("== pmdc-ident start-up")
        helps = measure("--help", ["--help"], args.repeat, scratch)
        eager = measure_eager_help(args.repeat)
        _ratio("--help", eager, helps["warm"][0], "eager-import reference / ours, wall")
        goals.append(_goal("pmdc-ident --help", helps["warm"], 0.3))
        measure("identify (argument error)", ["identify", "--bootstrap"], args.repeat, scratch)
        for label, path in runs.items():
            print(f"== {label}: {path.name}")
            cmd = ["identify", str(path), "--json", str(scratch / "identify.json")]
            rows = measure("identify", cmd, args.repeat, scratch, fits=True)
            _ratio("identify", rows["cold"][0], rows["warm"][0], "cold cache / warm, wall")
            if label.startswith("60 s"):
                goals.append(_goal("identify, 60 s at 1 kHz, warm", rows["warm"], 1.0))
            if not args.skip_diagnose:
                rows = measure("diagnose", ["diagnose", str(path)], args.repeat, scratch)
                _ratio("diagnose", rows["cold"][0], rows["warm"][0], "cold cache / warm, wall")
                if label.startswith("60 s"):
                    goals.append(_goal("diagnose, 60 s at 1 kHz, warm", rows["warm"], 5.0))
    if not args.skip_node:
        from bench_node_start import measure_node_start

        print("== identification node: launch to ready (status published)")
        ready, eager_ready = measure_node_start(args.repeat, _child_env())
        _ratio("node start", eager_ready, ready, "numba imported up front / ours, to ready")
        goals.append(_goal("identification node, launch to ready", (ready, []), 1.0))
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print("== issue 14 goals (warm, median of the runs above)")
    for line in goals:
        print(line)
    return 0


def _goal(name: str, row: tuple[list[float], list[float]], goal_s: float) -> str:
    wall = statistics.median(row[0])
    cpu = f", CPU {statistics.median(row[1]):.2f} s" if row[1] else ""
    verdict = "met" if wall <= goal_s else "MISSED"
    return f"  {name:<40} wall {wall:5.2f} s{cpu}  (goal <= {goal_s:g} s: {verdict})"


if __name__ == "__main__":
    sys.exit(main())
