"""Run the benchmark: write each case as a CSV run file, diagnose it from the file.

The diagnosis sees only the file (no truth, no label but the session's segment
names). Cases run in worker processes (``jobs``), each diagnosis single-threaded
then, so the full benchmark uses the machine's cores without oversubscribing.
"""

from __future__ import annotations

import enum
import os
import resource
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pmdc_ident.benchmark.cases import Case, Recording, record
from pmdc_ident.core.workers import WorkerError, WorkerPool

__all__ = [
    "GENERATOR_FAILED",
    "Failure",
    "Outcome",
    "generator_failures",
    "run_cases",
    "write_recording",
]

#: how a case the generator could not make is worded (its message's start, the summary)
GENERATOR_FAILED = "the generator could not simulate this run"


class Failure(enum.Enum):
    """Why a case has no verdict (its status is ``error``): matched by this code, never
    by the message's words (an error of the diagnosis may say anything)."""

    GENERATOR = "generator"  # the run could not be simulated: scored as a miss
    DIAGNOSIS = "diagnosis"  # the diagnosis refused or failed on the written file


@dataclass(frozen=True)
class Outcome:
    """What the diagnosis said about one case."""

    case: Case
    status: str  # no_gap / explained / unexplained / error
    effects: tuple[str, ...]
    ties: tuple[tuple[tuple[str, ...], str], ...] = ()  # (effects, separating test)
    shrink: float = float("nan")
    seconds: float = 0.0
    message: str = ""
    extra: dict[str, object] = field(default_factory=dict)
    failure: Failure | None = None  # set when status is "error"

    @property
    def top1(self) -> str:
        return self.effects[0] if self.effects else self.status


def write_recording(rec: Recording, path: Path) -> Path:
    """The recording as a CSV run file of the project's schema (segments contiguous)."""
    from pmdc_ident.core.data import Run, Segment, link_history
    from pmdc_ident.dataio.csvio import write_csv

    t = np.arange(rec.current.size) * rec.dt_s
    segs = []
    for label, (a, b) in zip(rec.labels, rec.bounds, strict=True):
        segs.append(
            Segment(
                label=label,
                t=t[a:b],
                voltage=rec.voltage[a:b],
                current=rec.current[a:b],
                position=rec.position[a:b],
                speed=None if rec.speed is None else rec.speed[a:b],
            )
        )
    return write_csv(Run(link_history(segs), "benchmark"), path)


def _cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def run_one(case: Case, directory: str, workers: int = 1) -> Outcome:
    """Generate, write and diagnose one case (in whatever process calls it)."""
    from pmdc_ident.core.diagnosis import DiagnosisConfig, diagnose
    from pmdc_ident.core.errors import PmdcError
    from pmdc_ident.dataio import load_data

    g0 = _cpu_s()
    try:
        if case.plant == "mujoco":
            from pmdc_ident.benchmark.mujoco_cases import record_mj

            rec, vis = record_mj(case)
        else:
            rec, vis = record(case)
    except (ValueError, ArithmeticError) as exc:
        # the generator's failure, not the diagnosis': reported and scored as a miss
        # (its visibility unmeasured, NaN, counts as visible; named nothing) rather
        # than ending the whole benchmark
        return Outcome(
            case, "error", (), message=f"{GENERATOR_FAILED}: {exc}", failure=Failure.GENERATOR
        )
    gen_cpu = _cpu_s() - g0
    if vis is not None:
        case = replace(case, visibility=vis.residual, visibility_raw=vis.raw)
    path = write_recording(rec, Path(directory) / f"run_{case.seed:010d}.csv")
    t0, c0 = time.perf_counter(), _cpu_s()
    try:
        res = diagnose(load_data(path), config=DiagnosisConfig(workers=workers)).to_json()
    except (PmdcError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        msg = f"{type(exc).__name__}: {exc}"
        return Outcome(case, "error", (), message=msg, failure=Failure.DIAGNOSIS)
    v = res["verdict"]
    ties = tuple((tuple(t["effects"]), str(t["separating_test"])) for t in v["ties"])
    shrink = res["holdout"]["shrink"]
    return Outcome(
        case,
        str(v["status"]),
        tuple(v["effects"]),
        ties,
        float("nan") if shrink is None else float(shrink),
        time.perf_counter() - t0,
        str(v["message"]),
        {"cpu_s": _cpu_s() - c0, "generate_cpu_s": gen_cpu, "samples": int(rec.current.size)},
    )


def run_cases(
    cases: Sequence[Case],
    *,
    jobs: int = 1,
    keep: Path | None = None,
    progress: Callable[[int, int, Outcome], None] | None = None,
) -> list[Outcome]:
    """Diagnose every case; outcomes in the order of ``cases``."""
    with tempfile.TemporaryDirectory(prefix="pmdc_bench_") as tmp:
        directory = keep or Path(tmp)
        directory.mkdir(parents=True, exist_ok=True)
        out: list[Outcome | None] = [None] * len(cases)
        if jobs <= 1:
            for k, c in enumerate(cases):
                out[k] = run_one(c, str(directory), workers=2)
                if progress:
                    progress(k + 1, len(cases), out[k])  # type: ignore[arg-type]
        else:
            # longest first keeps both workers busy to the end
            order = sorted(range(len(cases)), key=lambda k: -_cost(cases[k]))
            # workers that die with this process on Ctrl-C, SIGTERM, SIGHUP or kill -9
            # (core.workers: no forkserver, resource tracker or semaphores left behind)
            tasks = [(k, f"{__name__}:run_one", (cases[k], str(directory), 1)) for k in order]
            with WorkerPool(jobs) as pool:
                done = 0
                for k, value in pool.run(tasks):
                    if isinstance(value, WorkerError):
                        raise value
                    out[k] = value
                    done += 1
                    if progress:
                        progress(done, len(cases), out[k])  # type: ignore[arg-type]
    return [o for o in out if o is not None]


def generator_failures(outcomes: Sequence[Outcome]) -> list[str]:
    """The names of the cases the generator could not make (scored as misses)."""
    return [o.case.name for o in outcomes if o.failure is Failure.GENERATOR]


def _cost(case: Case) -> float:
    return case.rate_hz * case.bench_motor.params.mechanical_time_constant_s


def default_jobs() -> int:
    return max(1, min(2, os.cpu_count() or 1))
