"""Speed of the data-quality gate: `pmdc-ident check` on a 60 s, 1 kHz run (goal < 0.5 s).

Writes seed 000's default session stretched to 60 s (all four test types, demo
sensors) as CSV, then times, in the same run:

* the whole command ``pmdc-ident check RUN.csv`` in a fresh process (wall and
  the child's CPU time: start-up, imports, CSV parsing and the gate);
* the gate alone in this process (``core.quality.check_inputs`` on the loaded run);
* the reference it saves when it refuses bad data: the output-error fit of the
  same run (``pmdc-ident identify --no-holdout``), as a ratio.

Run: ``.venv/bin/python benchmarks/bench_check.py`` (the load average is printed:
on a shared machine the CPU times are the figures other processes do not distort).
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from bench_identify_speed import plan_60s  # noqa: E402

from pmdc_ident.core.excitation import synthesize_run  # noqa: E402
from pmdc_ident.core.motors import load_motor  # noqa: E402
from pmdc_ident.core.quality import GateInput, check_inputs  # noqa: E402
from pmdc_ident.dataio.csvio import write_csv  # noqa: E402
from pmdc_ident.dataio.units import load_input  # noqa: E402

EXE = str(Path(sys.executable).parent / "pmdc-ident")


def _child(argv: list[str]) -> tuple[float, float]:
    """Wall and CPU (user + sys) seconds of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(argv, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    spec = load_motor("seed000_ebike")
    plan, _ = plan_60s(spec)
    run = synthesize_run(spec.model, plan, spec.sensors, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        path = write_csv(run, Path(tmp) / "run60.csv")
        n = sum(s.n for s in run.segments)
        print(f"run: {n} samples, {plan.duration_s:.1f} s at 1 kHz; load {os.getloadavg()}")
        _child([EXE, "check", str(path)])  # warm the file cache
        checks = [_child([EXE, "check", str(path)]) for _ in range(5)]
        wall = sorted(w for w, _ in checks)[2]
        cpu = sorted(c for _, c in checks)[2]
        print(f"pmdc-ident check: median wall {wall:.3f} s, CPU {cpu:.3f} s (5 runs)")
        x = load_input(path)
        gate = []
        for _ in range(5):
            t0 = time.process_time()
            check_inputs([GateInput(x.path, x.run)])
            gate.append(time.process_time() - t0)
        gate_cpu = sorted(gate)[2]
        print(f"gate alone (in process): CPU {gate_cpu:.3f} s")
        fit_wall, fit_cpu = _child([EXE, "identify", str(path), "--quiet", "--no-holdout"])
        print(f"reference, identify (fit): wall {fit_wall:.2f} s, CPU {fit_cpu:.2f} s")
        print(f"check costs {cpu / fit_cpu:.1%} of the fit's CPU time it can save")


if __name__ == "__main__":
    main()
