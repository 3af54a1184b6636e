"""A 200 MB log as a normal input: `pmdc-ident check` and `identify` on 3.7 M rows at 1 kHz.

Writes, in a temporary folder, one unlabeled CSV log of about an hour at 1 kHz
(3.7 M rows, about 200 MB: the seed-000 e-bike motor's default session - staircase,
steps both ways, a chirp, a coast-down - repeated with fresh sensor noise, times
continuous, no segment column), then runs in fresh processes and measures:

* ``pmdc-ident check LOG`` and ``pmdc-ident identify LOG --json OUT``: wall time, peak
  memory (maximum resident set of the process), and when the first progress line
  came (seconds after start);
* the same two commands on a tenth of the log (370 k rows): the ratio of the times
  is the scaling (10 for a linear pipeline);
* the identified R, L, Ke, J, B against the simulated motor, and on the tenth-size log
  the same fit with ``--all-samples``: the effect of the representative subset the fit
  takes on a long record (docs/data-safety.md), on the estimates and their intervals.

Goals (issue 28): check <= 30 s, identify <= 60 s wall on this 2-core machine, <= 1 GB,
first progress line within 2 s. Not a timed test: run it by hand, under ``nice``,
never beside another benchmark::

    nice .venv/bin/python benchmarks/bench_large_input.py [--rows N] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

EXE = str(Path(sys.executable).parent / "pmdc-ident")


def _session(seed: int):  # noqa: ANN202
    from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
    from pmdc_ident.core.motors import load_motor

    spec = load_motor("seed000_ebike")
    plan = plan_for_motor(spec, 1e-3, SequenceConfig())
    run = synthesize_run(spec.model, plan, spec.sensors, seed=seed)
    cols = {
        name: np.concatenate([getattr(s, name) for s in run.segments])
        for name in ("voltage", "current", "position", "speed")
    }
    return cols, spec


def write_log(path: Path, rows: int, *, distinct: int = 6) -> dict[str, float]:
    """The log (see the module doc); returns its size and the time it took to write."""
    t0 = time.perf_counter()
    sessions = [_session(seed)[0] for seed in range(1, distinct + 1)]
    n_per = sessions[0]["voltage"].size
    written = 0
    k = 0
    pos_offset = 0.0
    with path.open("w") as fh:
        fh.write("t,voltage,current,position,speed\n")
        while written < rows:
            s = sessions[k % distinct]
            n = min(n_per, rows - written, *(a.size for a in s.values()))
            t = (written + np.arange(n)) * 1e-3
            v, i, p, w = (s[c][:n] for c in ("voltage", "current", "position", "speed"))
            p = p - p[0] + pos_offset
            pos_offset = float(p[-1]) + float(w[-1]) * 1e-3
            vs = ["" if math.isnan(x) else f"{x:.6g}" for x in v.tolist()]
            fh.write(
                "".join(
                    f"{a:.4f},{b},{c:.7f},{d:.7f},{e:.6f}\n"
                    for a, b, c, d, e in zip(
                        t.tolist(), vs, i.tolist(), p.tolist(), w.tolist(), strict=True
                    )
                )
            )
            written += n
            k += 1
    return {"rows": written, "mb": path.stat().st_size / 1e6, "seconds": time.perf_counter() - t0}


def run_command(argv: list[str]) -> dict[str, float | int | str]:
    """Wall time, CPU, peak memory (MB, this process alone: wait4) and the time of the
    first stderr line of one command."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, bufsize=1
    )
    first: list[float] = []
    lines: list[str] = []

    def read() -> None:
        assert proc.stderr is not None
        for line in proc.stderr:
            if not first:
                first.append(time.perf_counter() - t0)
            lines.append(line.rstrip())

    reader = threading.Thread(target=read)
    reader.start()
    _, status, ru = os.wait4(proc.pid, 0)
    proc.returncode = rc = os.waitstatus_to_exitcode(status)
    reader.join()
    wall = time.perf_counter() - t0
    return {
        "rc": rc,
        "wall_s": wall,
        "cpu_s": ru.ru_utime + ru.ru_stime,
        "max_rss_mb": ru.ru_maxrss / 1024.0,
        "first_line_s": first[0] if first else float("nan"),
        "last_line": lines[-1] if lines else "",
    }


def _truth() -> dict[str, float]:
    from pmdc_ident.core.motors import load_motor

    p = load_motor("seed000_ebike").model.params
    scale = p.Ke / p.Kt  # the Kt = Ke closure scales J and B
    return {"R": p.R, "L": p.L, "Ke": p.Ke, "J": p.J * scale, "B": p.B * scale}


def _accuracy(folder: Path, include_all: bool) -> None:
    """Each fit's estimates against the simulated motor, and its 95 % interval's width."""
    truth = _truth()
    names = ["large", "tenth"] + (["tenth_all"] if include_all else [])
    print(f"{'fit':<12} " + " ".join(f"{k + ' err %':>10} {k + ' ci %':>9}" for k in truth))
    for name in names:
        path = folder / f"{name}.json"
        if not path.is_file():
            continue
        params = json.loads(path.read_text())["parameters"]
        cells = []
        for k, v in truth.items():
            est = params[k]
            ci = est.get("ci95")
            width = 100 * (ci[1] - ci[0]) / 2 / est["value"] if ci else float("nan")
            cells.append(f"{100 * (est['value'] / v - 1):+10.3f} {width:9.3f}")
        print(f"{name:<12} " + " ".join(cells))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=3_700_000, help="rows of the large log")
    ap.add_argument("--keep", type=Path, default=None, help="write the logs here (kept)")
    ap.add_argument("--skip-small", action="store_true", help="no tenth-size run")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()}; {os.cpu_count()} CPUs", flush=True)
    with tempfile.TemporaryDirectory(prefix="pmdc_large_") as tmp:
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        results: dict[str, dict[str, float | int | str]] = {}
        sizes = [("large", args.rows)] + ([] if args.skip_small else [("tenth", args.rows // 10)])
        for name, rows in sizes:
            log = folder / f"{name}.csv"
            if not log.exists():
                info = write_log(log, rows)
                print(
                    f"{name}: {info['rows']} rows, {info['mb']:.0f} MB written in "
                    f"{info['seconds']:.0f} s",
                    flush=True,
                )
            for cmd in ("check", "identify"):
                argv = [EXE, cmd, str(log)]
                if cmd == "identify":
                    argv += ["--json", str(folder / f"{name}.json")]
                r = run_command(argv)
                results[f"{cmd} {name}"] = r
                print(
                    f"pmdc-ident {cmd} {name}.csv: exit {r['rc']}, wall {r['wall_s']:.1f} s, "
                    f"CPU {r['cpu_s']:.1f} s, peak RSS {r['max_rss_mb']:.0f} MB, first "
                    f"progress line after {r['first_line_s']:.2f} s ({r['last_line'][:100]})",
                    flush=True,
                )
        if not args.skip_small:
            for cmd in ("check", "identify"):
                big, small = results[f"{cmd} large"], results[f"{cmd} tenth"]
                ratio = float(big["wall_s"]) / float(small["wall_s"])
                cpu = float(big["cpu_s"]) / float(small["cpu_s"])
                print(f"{cmd}: 10x the rows takes {ratio:.1f}x the wall time, {cpu:.1f}x the CPU")
            argv = [EXE, "identify", str(folder / "tenth.csv"), "--all-samples"]
            r = run_command([*argv, "--json", str(folder / "tenth_all.json")])
            results["identify tenth --all-samples"] = r
            print(
                f"pmdc-ident identify tenth.csv --all-samples: exit {r['rc']}, wall "
                f"{r['wall_s']:.1f} s, CPU {r['cpu_s']:.1f} s, peak RSS {r['max_rss_mb']:.0f} MB"
            )
        _accuracy(folder, include_all=not args.skip_small)
        (folder / "bench.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
