"""``pmdc-ident benchmark``: the diagnosis checked on runs with withheld effects.

Generates sessions (staircase, steps both ways, log chirp, coast-down) from
motors of different sizes with effects drawn at random (type, magnitude, pairs,
noise level, sample rate) and effect-free sessions, writes each as a CSV run
file, and diagnoses it from the file alone (the truth stays in this process).
Then it scores top-1 accuracy per effect, the confusion matrix, false
attribution on effect-free runs and the median held-out shrink when the
attribution is right.

Magnitudes "a real motor shows", relative to the motor (``T_r`` = Kt x a quarter
of the stall current, ``w0`` = no-load speed at the voltage limit, ``Vmax`` the
voltage limit, ``I_r`` a quarter of the stall current):

=====================  ==============================================
coulomb_friction       5-30 % of T_r
stribeck_friction      10-40 % of T_r breakaway, Stribeck speed 2-10 % of w0
quadratic_drag         10-40 % of T_r at w0
load_torque            5-30 % of T_r, either sign
brush_drop             2-8 % of Vmax, within 0.5-3 V
dead_zone              2-8 % of Vmax
cogging                5-20 % of T_r, 2-12 periods per turn (resolvable at the rate)
resistance_drift       R rises 10-40 % over the session
delay                  2-20 samples
current_offset         2-10 % of I_r, either sign
inductance_saturation  L halves at 0.5-1.5 x the peak current (only where L/R
                       spans >= 2 samples: otherwise no data can show it)
=====================  ==============================================
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from pmdc_ident.core.effects import (
    EFFECT_NAMES,
    BrushDrop,
    Cogging,
    CoulombFriction,
    CurrentOffset,
    DeadZone,
    Delay,
    Effect,
    InductanceSaturation,
    LoadTorque,
    QuadraticDrag,
    ResistanceDrift,
    StribeckFriction,
)
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.params import MotorParams

if TYPE_CHECKING:
    import numpy as np

    from pmdc_ident.core.diagnosis import DiagnosisConfig
    from pmdc_ident.core.excitation import SequenceConfig
    from pmdc_ident.core.motors import MotorSpec

# numpy and the numerical core are imported inside the functions that use them, so
# that building the command line's help stays light (see pmdc_ident.cli).

HELP = "score the diagnosis on generated runs with withheld effects (accuracy, confusion)"

NONE = "none"  # truth / prediction label of "no effect"

# Motor archetypes: (params, voltage limit V, current noise A, speed noise rad/s)
ARCHETYPES: dict[str, tuple[MotorParams, float, float, float]] = {
    "hobby_12v": (MotorParams(2.0, 1.0e-3, 0.012, 0.012, 4.0e-6, 2.0e-7), 12.0, 0.005, 0.05),
    "ebike_24v": (MotorParams(1.375, 2.9875e-4, 0.0662, 0.0662, 9.9e-4, 7e-5), 24.0, 0.01, 0.05),
    "industrial_110v": (
        MotorParams(3.0484, 0.10419, 1.835, 1.835, 0.057419, 0.041202),
        110.0,
        0.01,
        0.05,
    ),
}
RATES_HZ: tuple[float, ...] = (500.0, 1000.0, 2000.0)
# The default session, with a shorter sweep and holds so a benchmark of ~80 runs
# fits in a coffee break.
BENCH_PLAN_TAU: dict[str, float] = {
    "sweep_duration_tau": 20.0,
    "staircase_hold_tau": 4.0,
    "step_hold_tau": 5.0,
}


def bench_plan() -> SequenceConfig:
    from pmdc_ident.core.excitation import SequenceConfig

    return SequenceConfig(**BENCH_PLAN_TAU)


@dataclass(frozen=True)
class Case:
    name: str
    archetype: str
    params: MotorParams
    effects: tuple[Effect, ...]
    rate_hz: float
    noise_factor: float
    voltage_max_v: float
    seed: int

    @property
    def truth(self) -> tuple[str, ...]:
        return tuple(e.NAME for e in self.effects)


@dataclass
class Outcome:
    case: Case
    status: str
    effects: tuple[str, ...]
    shrink: float
    elapsed_s: float
    ties: tuple[tuple[str, ...], ...] = field(default_factory=tuple)

    @property
    def top1(self) -> str:
        return self.effects[0] if self.effects else self.status


def _scales(p: MotorParams, vmax: float) -> dict[str, float]:
    i_r = 0.25 * vmax / p.R
    _, w0 = p.steady_state(vmax)
    return {"T_r": p.Kt * i_r, "I_r": i_r, "w0": abs(w0)}


def draw_effect(
    name: str, p: MotorParams, vmax: float, rate_hz: float, rng: np.random.Generator
) -> Effect:
    """One effect at a magnitude a real motor shows (module table)."""
    s = _scales(p, vmax)
    u = rng.uniform
    if name == "coulomb_friction":
        return CoulombFriction(u(0.05, 0.3) * s["T_r"])
    if name == "stribeck_friction":
        return StribeckFriction(u(0.1, 0.4) * s["T_r"], u(0.02, 0.1) * s["w0"])
    if name == "quadratic_drag":
        return QuadraticDrag(u(0.1, 0.4) * s["T_r"] / s["w0"] ** 2)
    if name == "load_torque":
        return LoadTorque(rng.choice([-1.0, 1.0]) * u(0.05, 0.3) * s["T_r"])
    if name == "brush_drop":
        return BrushDrop(min(max(u(0.02, 0.08) * vmax, 0.5), 3.0))
    if name == "dead_zone":
        return DeadZone(u(0.02, 0.08) * vmax)
    if name == "cogging":
        rev_per_s = s["w0"] / (2 * math.pi)
        n_max = max(2, int(rate_hz / rev_per_s / 4))
        choices = [n for n in (2, 3, 4, 6, 8, 12) if n <= n_max] or [2]
        return Cogging(u(0.05, 0.2) * s["T_r"], float(rng.choice(choices)), u(-math.pi, math.pi))
    if name == "resistance_drift":
        return ResistanceDrift(u(0.1, 0.4))  # rescaled to the session in make_case
    if name == "delay":
        return Delay(float(rng.integers(2, 21)) / rate_hz)
    if name == "current_offset":
        return CurrentOffset(rng.choice([-1.0, 1.0]) * u(0.02, 0.1) * s["I_r"])
    if name == "inductance_saturation":
        return InductanceSaturation(u(0.5, 1.5))  # rescaled to the peak current in make_case
    msg = f"unknown effect {name!r}"
    raise ParameterError(msg)


def _spec(case: Case, effects: tuple[Effect, ...]) -> MotorSpec:
    from pmdc_ident.core.model import Model
    from pmdc_ident.core.motors import Limits, MotorSpec, SensorSpec

    _, _, ni, nw = ARCHETYPES[case.archetype]
    f = case.noise_factor
    return MotorSpec(
        name=case.name,
        model=Model(case.params, effects),
        sensors=SensorSpec(current_noise_a=ni * f, speed_noise_rad_s=nw * f),
        limits=Limits(voltage_max_v=case.voltage_max_v, current_max_a=1e4, speed_max_rad_s=1e5),
    )


def make_case(name: str, effect_names: tuple[str, ...], rng: np.random.Generator) -> Case:
    """A random motor, rate and noise level carrying the named effects."""
    arch_names = list(ARCHETYPES)
    rates = list(RATES_HZ)
    if "inductance_saturation" in effect_names:
        ok = [
            (a, r)
            for a in arch_names
            for r in rates
            if ARCHETYPES[a][0].electrical_time_constant_s >= 2.0 / r
        ]
        arch, rate = ok[int(rng.integers(len(ok)))]
    else:
        arch = arch_names[int(rng.integers(len(arch_names)))]
        rate = rates[int(rng.integers(len(rates)))]
    base, vmax, _, _ = ARCHETYPES[arch]
    k = {n: float(rng.uniform(0.75, 1.33)) for n in ("R", "L", "Ke", "J", "B")}
    p = MotorParams(
        R=base.R * k["R"],
        L=base.L * k["L"],
        Ke=base.Ke * k["Ke"],
        Kt=base.Ke * k["Ke"],
        J=base.J * k["J"],
        B=base.B * k["B"],
    )
    effects = tuple(draw_effect(n, p, vmax, rate, rng) for n in effect_names)
    case = Case(
        name, arch, p, effects, rate, float(rng.uniform(0.5, 2.0)), vmax, int(rng.integers(2**31))
    )
    # effects sized from a clean session: drift over the session, saturation vs peak current
    if any(isinstance(e, (ResistanceDrift, InductanceSaturation)) for e in effects):
        import numpy as np

        from pmdc_ident.core.excitation import plan_for_motor
        from pmdc_ident.core.model import Model, simulate

        spec = _spec(case, ())
        plan = plan_for_motor(spec, 1.0 / rate, bench_plan())
        v = np.concatenate([s.voltage for s in plan.segments])
        sim = simulate(Model(p), v, 1.0 / rate)
        i_drive = np.where(np.isnan(v), 0.0, sim.current)
        charge = float(np.sum(i_drive**2) / rate)
        peak = float(np.max(np.abs(i_drive)))
        fixed = []
        for e in effects:
            if isinstance(e, ResistanceDrift):
                fixed.append(ResistanceDrift(min(e.coeff_per_a2s / max(charge, 1e-9), 10.0)))
            elif isinstance(e, InductanceSaturation):
                fixed.append(InductanceSaturation(max(e.saturation_current_a * peak, 1e-3)))
            else:
                fixed.append(e)
        case = Case(name, arch, p, tuple(fixed), rate, case.noise_factor, vmax, case.seed)
    return case


def generate_cases(runs_per_effect: int, clean_runs: int, pair_runs: int, seed: int) -> list[Case]:
    import numpy as np

    rng = np.random.default_rng(seed)
    cases: list[Case] = []
    for name in EFFECT_NAMES:
        for k in range(runs_per_effect):
            cases.append(make_case(f"{name}_{k:02d}", (name,), rng))
    for k in range(clean_runs):
        cases.append(make_case(f"clean_{k:02d}", (), rng))
    for k in range(pair_runs):
        a, b = rng.choice(len(EFFECT_NAMES), size=2, replace=False)
        pair = (EFFECT_NAMES[int(a)], EFFECT_NAMES[int(b)])
        if "inductance_saturation" in pair:
            pair = (pair[0], "coulomb_friction") if pair[1] == "inductance_saturation" else pair
        cases.append(make_case(f"pair_{k:02d}_{'+'.join(pair)}", pair, rng))
    return cases


def write_case(case: Case, directory: Path) -> Path:
    """Synthesize the session and write it as a CSV run file (no truth in the file)."""
    from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
    from pmdc_ident.dataio.csvio import write_csv

    spec = _spec(case, case.effects)
    plan = plan_for_motor(_spec(case, ()), 1.0 / case.rate_hz, bench_plan())
    run = synthesize_run(spec.model, plan, spec.sensors, seed=case.seed, source=case.name)
    path = directory / f"run_{abs(hash(case.name)) % 10**8:08d}.csv"
    write_csv(run, path)
    return path


def run_case(case: Case, directory: Path, config: DiagnosisConfig) -> Outcome:
    from pmdc_ident.core.diagnosis import diagnose
    from pmdc_ident.dataio import load_data

    path = write_case(case, directory)
    t0 = time.perf_counter()
    res = diagnose(load_data(path), config=config)
    return Outcome(
        case,
        res.verdict.status.value,
        tuple(res.verdict.effects),
        res.shrink,
        time.perf_counter() - t0,
        tuple(t.effects for t in res.verdict.ties),
    )


@dataclass(frozen=True)
class Score:
    per_effect: dict[str, tuple[int, int]]  # effect -> (right, total), single-effect runs
    top1: float  # over single-effect runs
    false_attribution: float  # clean runs with an effect named
    clean_total: int
    median_shrink_right: float
    confusion: dict[str, dict[str, int]]
    pairs_both: tuple[int, int]  # pair runs with both effects named, of total
    pairs_one: tuple[int, int]  # pair runs whose first named effect is one of the two

    def table(self) -> str:
        lines = ["| effect | top-1 | runs |", "|---|---:|---:|"]
        for name, (ok, n) in self.per_effect.items():
            lines.append(f"| {name} | {ok / n:.0%} | {n} |" if n else f"| {name} | - | 0 |")
        lines.append(
            f"| **all effects (top-1)** | **{self.top1:.0%}** | "
            f"{sum(n for _, n in self.per_effect.values())} |"
        )
        lines.append(
            f"| effect-free runs: false attribution | {self.false_attribution:.0%} | "
            f"{self.clean_total} |"
        )
        lines.append(f"| median held-out shrink when right | {self.median_shrink_right:.0%} | |")
        if self.pairs_both[1]:
            lines.append(
                f"| pairs: first named is one of the two | "
                f"{self.pairs_one[0] / self.pairs_one[1]:.0%} | {self.pairs_one[1]} |"
            )
            lines.append(
                f"| pairs: both named | {self.pairs_both[0] / self.pairs_both[1]:.0%} | "
                f"{self.pairs_both[1]} |"
            )
        return "\n".join(lines)

    def confusion_text(self) -> str:
        cols = sorted({c for row in self.confusion.values() for c in row})
        head = "truth \\ predicted".ljust(24) + " ".join(c[:11].rjust(11) for c in cols)
        rows = [head]
        for truth, row in self.confusion.items():
            rows.append(
                truth[:24].ljust(24) + " ".join(str(row.get(c, 0)).rjust(11) for c in cols)
            )
        return "\n".join(rows)


def score(outcomes: list[Outcome]) -> Score:
    per: dict[str, list[int]] = {n: [0, 0] for n in EFFECT_NAMES}
    confusion: dict[str, Counter[str]] = {}
    shrinks: list[float] = []
    clean = [o for o in outcomes if not o.case.truth]
    pairs = [o for o in outcomes if len(o.case.truth) > 1]
    for o in outcomes:
        if len(o.case.truth) > 1:
            continue
        truth = o.case.truth[0] if o.case.truth else NONE
        confusion.setdefault(truth, Counter())[o.top1] += 1
        if truth == NONE:
            continue
        per[truth][1] += 1
        if o.top1 == truth:
            per[truth][0] += 1
            shrinks.append(o.shrink)
    total = sum(n for _, n in per.values())
    right = sum(k for k, _ in per.values())
    false_attr = sum(1 for o in clean if o.effects) / len(clean) if clean else 0.0
    both = sum(1 for o in pairs if set(o.case.truth) <= set(o.effects))
    one = sum(1 for o in pairs if o.effects and o.effects[0] in o.case.truth)
    return Score(
        per_effect={k: (v[0], v[1]) for k, v in per.items()},
        top1=right / total if total else 0.0,
        false_attribution=false_attr,
        clean_total=len(clean),
        median_shrink_right=statistics.median(shrinks) if shrinks else math.nan,
        confusion={k: dict(v) for k, v in confusion.items()},
        pairs_both=(both, len(pairs)),
        pairs_one=(one, len(pairs)),
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--runs-per-effect", type=int, default=5, metavar="N")
    parser.add_argument("--clean", type=int, default=20, metavar="N", help="effect-free runs")
    parser.add_argument("--pairs", type=int, default=6, metavar="N", help="runs with two effects")
    parser.add_argument("--seed", type=int, default=1, help="random seed of the draw")
    parser.add_argument(
        "--effects",
        default=",".join(EFFECT_NAMES),
        metavar="NAME,...",
        help="restrict the single-effect runs to these effects",
    )
    parser.add_argument("--keep", metavar="DIR", help="keep the generated run files here")
    parser.add_argument("--json", metavar="PATH", help="write every outcome and the score")
    parser.add_argument("--quiet", action="store_true", help="no per-run lines on stderr")


def run(args: argparse.Namespace) -> int:
    from pmdc_ident.commands.outputs import check_file_output, check_folder_output
    from pmdc_ident.core.diagnosis import DiagnosisConfig

    if min(args.runs_per_effect, args.clean, args.pairs) < 0:
        msg = "--runs-per-effect, --clean and --pairs must be >= 0"
        raise ParameterError(msg)
    # checked before the (long) run, not after it
    check_file_output("--json", args.json, [], suffixes=(".json",), stdout_ok=False)
    check_folder_output("--keep", args.keep, [])
    only = [e.strip() for e in args.effects.split(",") if e.strip()]
    unknown = [e for e in only if e not in EFFECT_NAMES]
    if unknown:
        msg = f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(EFFECT_NAMES)}"
        raise ParameterError(msg)
    cases = [
        c
        for c in generate_cases(args.runs_per_effect, args.clean, args.pairs, args.seed)
        if len(c.truth) != 1 or c.truth[0] in only
    ]
    config = DiagnosisConfig()
    outcomes: list[Outcome] = []
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="pmdc_bench_") as tmp:
        directory = Path(args.keep) if args.keep else Path(tmp)
        directory.mkdir(parents=True, exist_ok=True)
        for k, case in enumerate(cases, 1):
            o = run_case(case, directory, config)
            outcomes.append(o)
            if not args.quiet:
                mark = "ok " if (o.top1 == (case.truth[0] if case.truth else "no_gap")) else "-- "
                print(
                    f"[{k}/{len(cases)} {time.perf_counter() - t0:6.0f} s] {mark}{case.name} "
                    f"({case.archetype}, {case.rate_hz:g} Hz): {o.status} "
                    f"{'+'.join(o.effects)} shrink {o.shrink:.0%} ({o.elapsed_s:.1f} s)",
                    file=sys.stderr,
                    flush=True,
                )
    sc = score(outcomes)
    print(sc.table())
    print()
    print(sc.confusion_text())
    print(f"\n{len(outcomes)} runs in {time.perf_counter() - t0:.0f} s (seed {args.seed})")
    if args.json:
        Path(args.json).write_text(
            json.dumps(
                {
                    "score": {
                        "top1": sc.top1,
                        "false_attribution": sc.false_attribution,
                        "median_shrink_right": sc.median_shrink_right,
                        "per_effect": sc.per_effect,
                        "confusion": sc.confusion,
                    },
                    "runs": [
                        {
                            "name": o.case.name,
                            "archetype": o.case.archetype,
                            "rate_hz": o.case.rate_hz,
                            "truth": list(o.case.truth),
                            "truth_parameters": {e.NAME: e.as_dict() for e in o.case.effects},
                            "status": o.status,
                            "effects": list(o.effects),
                            "shrink": o.shrink,
                            "elapsed_s": o.elapsed_s,
                        }
                        for o in outcomes
                    ],
                },
                indent=2,
            )
            + "\n"
        )
    return 0
