"""What scipy would cost ``pmdc-ident identify`` in place of the hand-written pieces.

    .venv/bin/python benchmarks/bench_scipy_imports.py [--repeats N]

Three pieces are written by hand where scipy has them: Student's t quantile
(``core/estimators/student_t.py``, scipy: ``scipy.special.stdtrit``), the small
matrix exponential (``core/model.expm_small``, scipy: ``scipy.linalg.expm``) and the
2x2 matrix logarithm (``core/estimators/equation_error.logm_2x2``, scipy:
``scipy.linalg.logm``). ``identify`` imports neither ``scipy.special`` nor
``scipy.linalg`` (only ``scipy.linalg.cython_blas`` for numba). This prints, each
measured in fresh interpreters in the same run (median of ``--repeats``):

* the CPU time of ``pmdc-ident identify`` on the seed-000 staircase table and on a 1 kHz
  session, and what importing ``scipy.special`` / ``scipy.linalg`` adds to an
  interpreter that has numpy (the cost each replacement would add to every call);
* per call, ``t_quantile`` against ``stdtrit`` and ``expm_small`` against
  ``scipy.linalg.expm`` on the 5x5 and 10x10 matrices of the fits, and how far apart
  their results are.

The per-call figures are taken in this process with the threads the environment gives
BLAS, as a user runs it. The pieces stay by hand while the import adds a sizeable share
of identify's CPU.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ENV_THREADS = {"OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}


def _cpu_of(code: str) -> float:
    """CPU seconds (user + system) of a fresh interpreter running ``code``."""
    probe = (
        "import resource, json\n"
        f"{code}\n"
        "ru = resource.getrusage(resource.RUSAGE_SELF)\n"
        "print(json.dumps(ru.ru_utime + ru.ru_stime))\n"
    )
    env = {**os.environ, **ENV_THREADS}
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, check=True, env=env
    )
    return float(out.stdout.strip().splitlines()[-1])


def _median_cpu(code: str, repeats: int) -> float:
    return statistics.median(_cpu_of(code) for _ in range(repeats))


def _session_csv(folder: Path) -> Path:
    """A 1 kHz session of the built-in e-bike motor (staircase, steps, chirp, coast)."""
    from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.dataio.csvio import write_csv

    spec = load_motor("seed000_ebike")
    plan = plan_for_motor(spec, 1e-3, SequenceConfig())
    run = synthesize_run(spec.model, plan, spec.sensors, seed=1)
    out = write_csv(run, folder / "session.csv")
    assert isinstance(out, Path)
    return out


def _per_call(fn, args, n: int) -> float:  # type: ignore[no-untyped-def]
    fn(*args)  # warm (numba compiles or loads)
    t0 = time.perf_counter()
    for _ in range(n):
        fn(*args)
    return (time.perf_counter() - t0) / n


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args()
    n = args.repeats
    table = ROOT / "test" / "fixtures" / "seed000_table4.csv"
    with tempfile.TemporaryDirectory() as tmp:
        session = _session_csv(Path(tmp))
        ident = (
            "from pmdc_ident.cli import main\nmain(['identify', {!r}, '--quiet', '--json', {!r}])"
        )
        out_json = str(Path(tmp) / "out.json")
        cpu_table = _median_cpu(ident.format(str(table), out_json), n)
        cpu_session = _median_cpu(ident.format(str(session), out_json), n)
    base = _median_cpu("import numpy", n)
    special = _median_cpu("import numpy, scipy.special", n) - base
    linalg = _median_cpu("import numpy, scipy.linalg", n) - base
    print(f"CPU of pmdc-ident identify (median of {n} fresh processes):")
    print(f"  seed-000 staircase table: {cpu_table:.3f} s; 1 kHz session: {cpu_session:.3f} s")
    print("what the import adds to an interpreter with numpy:")
    for name, cost in (
        ("scipy.special (stdtrit)", special),
        ("scipy.linalg (expm, logm)", linalg),
    ):
        print(
            f"  {name:26s} {cost:.3f} s = {cost / cpu_table:.0%} of identify on the table, "
            f"{cost / cpu_session:.0%} on the session"
        )

    from scipy.linalg import expm
    from scipy.special import stdtrit

    from pmdc_ident.core.estimators.output_error.simulators import system_matrices
    from pmdc_ident.core.estimators.student_t import t_quantile
    from pmdc_ident.core.model import expm_small
    from pmdc_ident.core.params import MotorParams

    dofs = [1.0, 2.5, 10.0, 57.0, 299.0, 1000.0, 1e5]
    worst_t = max(abs(t_quantile(0.975, d) / stdtrit(d, 0.975) - 1.0) for d in dofs)
    t_ours = _per_call(t_quantile, (0.975, 57.0), 2000)
    t_scipy = _per_call(stdtrit, (57.0, 0.975), 2000)
    print(
        f"t quantile: ours {t_ours * 1e6:.1f} us, stdtrit {t_scipy * 1e6:.1f} us per call; "
        f"largest relative difference {worst_t:.1e}"
    )
    m5, dms = system_matrices(MotorParams(1.4, 2.2e-4, 0.066, 0.066, 1e-3, 7e-5), True)
    m5 = m5 * 1e-3
    m10 = np.zeros((10, 10))
    m10[:5, :5] = m10[5:, 5:] = m5
    m10[:5, 5:] = dms[0] * 1e-3
    for name, m in (("5x5", m5), ("10x10", m10)):
        ours = _per_call(expm_small, (m,), 2000)
        ref = _per_call(expm, (m,), 2000)
        diff = float(np.max(np.abs(expm_small(m) - expm(m))) / np.max(np.abs(expm(m))))
        print(
            f"expm {name}: ours {ours * 1e6:.1f} us, scipy {ref * 1e6:.1f} us per call "
            f"(ratio {ref / ours:.1f}); largest relative difference {diff:.1e}"
        )
    figures = {
        "identify_table_cpu_s": cpu_table,
        "identify_session_cpu_s": cpu_session,
        "import_special_cpu_s": special,
        "import_linalg_cpu_s": linalg,
    }
    print(json.dumps(figures))


if __name__ == "__main__":
    main()
