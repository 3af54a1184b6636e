"""Fill the on-disk numba cache once, while the suite's workers start (test/conftest.py).

On a fresh clone the cache is empty, and every process that reaches a kernel before
another has written it compiles it again: each pytest worker, and each node, CLI and
benchmark process the tests start early on. Started by the xdist controller, this
compiles the kernels the suite uses into the cache the tests then load; the workers
begin with tests that compile nothing (conftest's ordering) and never wait for it.

It only fills a cache: it checks nothing, and the suite's result does not depend on it
(a kernel it misses, or has not reached yet, is compiled by the first process that
calls it, as without it). Every step is independent; one that fails is reported on
stderr and the rest run.
"""

from __future__ import annotations

import contextlib
import io
import sys
import tempfile
import time
import traceback
from collections.abc import Callable
from pathlib import Path


def _identify(tmp: Path) -> None:  # the model's kernels and the output-error fit
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.process.identify_call import warm_up

    warm_up(load_motor("seed001_110v"))


def _diagnose(tmp: Path) -> None:  # the effects' kernel, heating and delay lines
    from pmdc_ident.core.diagnosis import diagnose
    from pmdc_ident.core.effects import Delay, ResistanceDrift
    from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
    from pmdc_ident.core.model import Model
    from pmdc_ident.core.motors import load_motor

    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, 1 / 250.0, SequenceConfig(sweep_duration_tau=5.0))
    model = Model(spec.model.params, (ResistanceDrift(0.002, 6.0), Delay(0.008)))
    diagnose(synthesize_run(model, plan, spec.sensors, seed=3))


def _commands(tmp: Path) -> None:  # CSV and MCAP scans, segmentation, outliers, drift, plan
    from pmdc_ident.cli import main
    from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.core.segmentation import find_segments
    from pmdc_ident.dataio.bagio import read_driver_arrays, write_bag
    from pmdc_ident.dataio.csvio import write_csv

    spec = load_motor("seed000_ebike")
    run = synthesize_run(spec.model, plan_for_motor(spec, 1e-3), spec.sensors, seed=1)
    csv = write_csv(run, tmp / "run.csv")
    bag = write_bag(run, tmp / "bag")
    read_driver_arrays(bag)
    find_segments(run.segments[0])
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        main(["identify", str(csv), "--json", str(tmp / "run.json")])
        main(["monitor", str(csv), "--params", "seed000_ebike"])
        main(["plan", "seed001_110v", "--json", str(tmp / "plan.json")])


def _benchmark_plant(tmp: Path) -> None:  # the benchmark's own plant and its linear twin
    import numpy as np

    from pmdc_ident.benchmark import plant as pl
    from pmdc_ident.benchmark.sensors import SensorSetup
    from pmdc_ident.benchmark.visibility import linear_signals
    from pmdc_ident.core.motors import load_motor

    p0 = load_motor("seed001_110v").model.params
    p = pl.new_params(p0.R, p0.L, p0.Ke, p0.Kt, p0.J, p0.B)
    v = np.full(200, 12.0)
    v[150:] = np.nan
    pl.simulate_plant(v, 1e-3, p)
    linear_signals(v, 1e-3, p, SensorSetup(1.0, 12, 0.0, 0.0, 1, 1000.0, "position", 0.0, 0.0))


#: The benchmark plant first: the quick benchmark commands run it in-process early in each
#: worker (conftest's _LONG), and on a fresh clone they reached it before the warm-up
#: did and compiled it themselves (their own CPU 7.2 and 4.8 s, against 1.3 and 1.2 s
#: with it cached); it costs the warm-up ~7 CPU-s, so the fits' kernels come ~15 s later.
STEPS: tuple[Callable[[Path], None], ...] = (_benchmark_plant, _identify, _diagnose, _commands)


def main() -> int:
    from pmdc_ident.core.workers import die_with_parent

    die_with_parent()  # never outlives the suite that started it
    t0, c0 = time.monotonic(), time.process_time()
    with tempfile.TemporaryDirectory(prefix="pmdc_warm_") as d:
        for step in STEPS:
            try:
                step(Path(d))
            except BaseException:  # noqa: BLE001 - a cache filler never fails the suite
                print(f"kernel warm-up: {step.__name__} failed:", file=sys.stderr)
                traceback.print_exc()
    print(
        f"kernel warm-up: {time.monotonic() - t0:.1f} s, {time.process_time() - c0:.1f} s CPU",
        file=sys.stderr,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
