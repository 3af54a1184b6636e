"""Record what the package says on a fixed set of inputs, and compare two recordings.

Written for refactorings that must not change behaviour (issue 26): record once on
the base commit, once on the branch, and compare run by run::

    # on the base tree (e.g. git archive 9f585c2 | tar -x -C /tmp/base)
    nice .venv/bin/python benchmarks/compare_behaviour.py record /tmp/before --src /tmp/base
    # on the branch
    nice .venv/bin/python benchmarks/compare_behaviour.py record /tmp/after
    .venv/bin/python benchmarks/compare_behaviour.py compare /tmp/before /tmp/after

``record`` writes, under its directory:

* ``identify/<name>.json``: ``pmdc-ident identify --json`` on the seed fixtures and on
  motor records made by ``test/helpers/motor_records.py`` (an RK4 integration that
  shares no code with the package);
* ``bench/runs.json`` and ``bench/runs/*.csv``: a reduced benchmark draw
  (``pmdc-ident benchmark --seed 1 --jobs 1 ...``, every run's truth, verdict and
  shrink) and the run files it generated;
* ``bench/diagnose/<run>.json``: ``pmdc-ident diagnose --json`` on every kept run file;
* ``diagnose/<name>.json``: ``pmdc-ident diagnose --json`` on three records.

``compare`` walks the two trees: strings, booleans, verdicts and effect lists must be
identical, numbers equal to ``--rtol`` (default 1e-9, relative; an absolute floor of
``--atol`` for values near zero); wall and CPU times are skipped. It prints one line
per difference and a summary, and exits 1 when anything differs.

``--src DIR`` runs the package found in DIR (its ``pmdc_ident``) instead of the one
installed in the environment, so one environment records both trees.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# the reduced benchmark draw
BENCH_ARGS = [
    "--seed",
    "1",
    "--jobs",
    "1",
    "--runs-per-effect",
    "3",
    "--clean",
    "6",
    "--oov",
    "2",
    "--pairs",
    "3",
    "--quiet",
]
# keys whose values are timings or paths of this machine, not behaviour
SKIP_KEYS = frozenset({"seconds", "cpu_s", "wall_s", "elapsed_s", "sources", "source", "path"})


def _env(src: Path | None) -> dict[str, str]:
    env = dict(os.environ)
    for k in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS"):
        env[k] = "1"
    if src is not None:
        env["PYTHONPATH"] = str(src) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _cli(args: list[str], src: Path | None) -> None:
    cmd = [sys.executable, "-c", "from pmdc_ident.cli import main; raise SystemExit(main())"]
    t0 = time.perf_counter()
    res = subprocess.run(
        [*cmd, *args],
        env=_env(src),
        capture_output=True,
        text=True,
        check=False,
        cwd=src or ROOT,  # `python -c` puts the working directory first on sys.path
    )
    print(f"  {time.perf_counter() - t0:6.1f} s  pmdc-ident {' '.join(args)}", flush=True)
    if res.returncode != 0:
        print(res.stderr.strip().splitlines()[-1] if res.stderr else "(no stderr)")
        msg = f"pmdc-ident {args[0]} failed ({res.returncode})"
        raise SystemExit(msg)


def _motor_records(out: Path) -> dict[str, Path]:
    """CSV records from test/helpers/motor_records.py (an RK4 integration)."""
    sys.path.insert(0, str(ROOT / "test"))
    import numpy as np
    from helpers import motor_records as mr

    out.mkdir(parents=True, exist_ok=True)
    recs: dict[str, Path] = {}
    v = mr.continuous_voltage(1000)
    linear = mr.simulate(mr.Motor(), v, 1000, noise_current=0.01, noise_speed=0.2, seed=3)
    recs["linear_1khz"] = mr.write_csv(out / "linear_1khz.csv", linear)
    fric = mr.Motor(Tc=0.004, T_load=0.0)
    coul = mr.simulate(fric, v, 1000, noise_current=0.01, noise_speed=0.2, seed=4)
    recs["coulomb_1khz"] = mr.write_csv(out / "coulomb_1khz.csv", coul)
    # one direction, 50 Hz, speed in rpm, no position: a user's log
    v50 = mr.steps([3.0, 6.0, 9.0, 12.0, None, 6.0], 1.5, 50)
    slow = mr.simulate(
        mr.Motor(J=2e-4, Tc=0.002), v50, 50, noise_current=0.02, noise_speed=0.3, seed=5
    )
    recs["rpm_50hz"] = mr.write_csv(
        out / "rpm_50hz.csv",
        slow,
        headers={"speed": "speed_rpm"},
        scale={"speed": 60.0 / (2.0 * math.pi)},
        drop=("position",),
    )
    # a closed-loop record (PI speed controller)
    ref = np.concatenate([np.full(1500, 100.0), np.full(1500, 250.0), np.full(1500, 50.0)])
    closed = mr.simulate(
        mr.Motor(Tc=0.003),
        np.zeros(ref.size),
        1000,
        noise_current=0.01,
        noise_speed=0.2,
        seed=6,
        controller=mr.speed_pi(ref),
    )
    recs["closed_loop"] = mr.write_csv(out / "closed_loop.csv", closed)
    return recs


def record(out: Path, src: Path | None, skip_bench: bool) -> None:
    out.mkdir(parents=True, exist_ok=True)
    fixtures = ROOT / "test" / "fixtures"
    recs = _motor_records(out / "records")
    ident = out / "identify"
    ident.mkdir(exist_ok=True)
    print("identify:", flush=True)
    jobs: dict[str, list[str]] = {
        "seed000_table4": [str(fixtures / "seed000_table4.csv")],
        "seed000_both": [str(fixtures / f"seed000_{n}.csv") for n in ("table4", "retardation")],
        **{name: [str(p)] for name, p in recs.items()},
    }
    extra = {"rpm_50hz": ["--speed-unit", "rpm", "--column", "speed=speed_rpm"]}
    for name, data in jobs.items():
        _cli(
            [
                "identify",
                *data,
                *extra.get(name, []),
                "--quiet",
                "--json",
                str(ident / f"{name}.json"),
            ],
            src,
        )
    # same data, the other models and a fixed value
    _cli(
        ["identify", str(recs["coulomb_1khz"]), "--model", "linear", "--fix", "L=2e-3",
         "--quiet", "--json", str(ident / "coulomb_1khz_linear_fixL.json")],
        src,
    )  # fmt: skip
    diag = out / "diagnose"
    diag.mkdir(exist_ok=True)
    print("diagnose:", flush=True)
    for name in ("linear_1khz", "coulomb_1khz", "closed_loop"):
        _cli(["diagnose", str(recs[name]), "--json", str(diag / f"{name}.json")], src)
    if skip_bench:
        return
    bench = out / "bench"
    bench.mkdir(exist_ok=True)
    print("benchmark:", flush=True)
    _cli(
        [
            "benchmark",
            *BENCH_ARGS,
            "--keep",
            str(bench / "runs"),
            "--json",
            str(bench / "runs.json"),
        ],
        src,
    )
    # the generated run files: the generator's output, compared by hash
    hashes = {
        p.name: hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted((bench / "runs").glob("*.csv"))
    }
    (bench / "run_files.json").write_text(json.dumps(hashes, indent=1) + "\n")
    diagnose_kept_runs(out, src)


def diagnose_kept_runs(out: Path, src: Path | None) -> None:
    """``diagnose --json`` on every run file the benchmark kept: every number, not only
    the verdict and shrink its JSON holds."""
    bench = out / "bench"
    (bench / "diagnose").mkdir(exist_ok=True)
    for p in sorted((bench / "runs").glob("*.csv")):
        _cli(["diagnose", str(p), "--json", str(bench / "diagnose" / f"{p.stem}.json")], src)


# ---------------------------------------------------------------------------
def _diff(a: object, b: object, where: str, rtol: float, atol: float, out: list[str]) -> int:
    """Number of leaves compared; differences appended to ``out``."""
    if isinstance(a, dict) and isinstance(b, dict):
        n = 0
        for k in sorted(set(a) | set(b)):
            if k in SKIP_KEYS or k.endswith(("_cpu_s", "_wall_s")):  # a time, not a result
                continue
            if k not in a or k not in b:
                out.append(f"{where}.{k}: only in {'after' if k in b else 'before'}")
                continue
            n += _diff(a[k], b[k], f"{where}.{k}", rtol, atol, out)
        return n
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            out.append(f"{where}: length {len(a)} -> {len(b)}")
            return 1
        pairs = enumerate(zip(a, b, strict=True))
        return sum(_diff(x, y, f"{where}[{i}]", rtol, atol, out) for i, (x, y) in pairs)
    num = (int, float)
    if isinstance(a, num) and isinstance(b, num) and not isinstance(a, bool):
        fa, fb = float(a), float(b)
        if math.isnan(fa) and math.isnan(fb):
            return 1
        if fa == fb or abs(fa - fb) <= max(atol, rtol * max(abs(fa), abs(fb))):
            return 1
        rel = abs(fa - fb) / max(abs(fa), abs(fb), 1e-300)
        out.append(f"{where}: {fa!r} -> {fb!r} (rel {rel:.2g})")
        return 1
    if a != b:
        out.append(f"{where}: {a!r} -> {b!r}")
    return 1


def _load(path: Path, root: Path) -> object:
    """The JSON at ``path`` with the recording's own folder written as ``<root>`` and the
    fixtures' as ``<fixtures>`` (the inputs' paths differ between two recordings, not
    their content)."""
    text = path.read_text().replace(str(root.resolve()), "<root>")
    # the seed fixtures, read from whichever source tree recorded
    return json.loads(re.sub(r'[^"\s]*/test/fixtures/', "<fixtures>/", text))


def compare(before: Path, after: Path, rtol: float, atol: float) -> int:
    files = sorted(p.relative_to(before) for p in before.rglob("*.json"))
    total_diffs = 0
    for rel in files:
        other = after / rel
        if not other.exists():
            print(f"{rel}: missing after")
            total_diffs += 1
            continue
        diffs: list[str] = []
        a, b = _load(before / rel, before), _load(other, after)
        n = _diff(a, b, "", rtol, atol, diffs)
        status = "identical" if not diffs else f"{len(diffs)} difference(s)"
        print(f"{rel}: {n} values compared, {status}")
        for d in diffs[:40]:
            print(f"    {d}")
        total_diffs += len(diffs)
    print(f"{len(files)} files, {total_diffs} difference(s) (rtol {rtol:g}, atol {atol:g})")
    return 1 if total_diffs else 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("record", help="run the package on the fixed inputs")
    r.add_argument("out", type=Path)
    r.add_argument("--src", type=Path, help="a source tree whose pmdc_ident to run")
    r.add_argument("--skip-bench", action="store_true", help="identify and diagnose only")
    r.add_argument(
        "--kept-only", action="store_true", help="only diagnose the run files already kept"
    )
    c = sub.add_parser("compare", help="compare two recordings")
    c.add_argument("before", type=Path)
    c.add_argument("after", type=Path)
    c.add_argument("--rtol", type=float, default=1e-9)
    c.add_argument("--atol", type=float, default=1e-15)
    args = p.parse_args(argv)
    if args.cmd == "record":
        src = args.src.resolve() if args.src else None
        if args.kept_only:
            diagnose_kept_runs(args.out.resolve(), src)
        else:
            record(args.out.resolve(), src, args.skip_bench)
        return 0
    return compare(args.before, args.after, args.rtol, args.atol)


if __name__ == "__main__":
    raise SystemExit(main())
