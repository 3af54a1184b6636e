"""``pmdc-ident plan MOTOR [--travel-rad MIN MAX] [--target ...] [--csv OUT.csv]``.

Designs the shortest safe experiment for a motor (:mod:`pmdc_ident.core.design`):
from a prior (a built-in motor, the YAML ``identify --yaml`` writes, or a recorded
pre-test, which is identified first), the driver's limits, the sample rate, the rig's
noise and a target, the plan that reaches the target in the least motor time. Prints
the plan, its duration, the predicted relative sd per parameter and the limit that
binds; ``--csv`` writes the planned voltage in the CSV exchange format (``t``,
``voltage`` empty while the armature is open, ``segment``), which a simulator or a rig
plays and ``pmdc-ident identify`` fits once current and position or speed are logged
beside it. ``--pretest OUT.csv`` writes the automatic pre-test (at most 2 s) instead.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from pmdc_ident.core.errors import ParameterError

HELP = (
    "design the shortest safe experiment reaching a target uncertainty (prints the plan; "
    "--csv writes it for a rig or simulator to play)"
)
_DATA_SUFFIXES = (".csv", ".mcap")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "motor",
        metavar="MOTOR",
        help="the prior: a built-in motor, a motor YAML (as identify --yaml writes), or a "
        "recorded pre-test (CSV, .mcap, bag folder), identified first",
    )
    parser.add_argument(
        "--travel-rad",
        nargs=2,
        type=float,
        metavar=("MIN", "MAX"),
        help="the joint's travel range in the encoder's frame, rad: the plan keeps the angle "
        "inside it (with a margin) at every instant, and a stop at any instant too",
    )
    parser.add_argument(
        "--start-rad", type=float, default=0.0, help="where the joint rests at the start (rad)"
    )
    parser.add_argument(
        "--travel-margin-rad",
        type=float,
        default=None,
        help="margin kept from each end of the travel range (default 10 %% of the range)",
    )
    parser.add_argument(
        "--command-delay",
        type=float,
        default=None,
        metavar="S",
        help="with --travel-rad: the joint stays inside also when a command (a stop, a "
        "switch) reaches the motor this late, the last one held meanwhile (default 0.15 s)",
    )
    parser.add_argument(
        "--target",
        default=None,
        metavar="NAME=SD,...",
        help="relative sd to reach per parameter, e.g. 'R=1%%,J=0.5%%,L=off' (default: R, "
        "L, Ke, J, B 1 %%, the Coulomb torque Tc 5 %%)",
    )
    parser.add_argument(
        "--reveal",
        default="",
        metavar="EFFECT,...",
        help="add segments that make these effects visible to `diagnose` (e.g. "
        "cogging,stribeck_friction)",
    )
    parser.add_argument(
        "--reveal-size",
        default="",
        metavar="EFFECT=SIZE,...",
        help="with --reveal: the smallest size each effect must show, in its unit (a torque "
        "in N*m for cogging and friction), e.g. 'cogging=0.02': the plan's predicted "
        "detection limit is judged against it (the plan is not grown: a longer plan does "
        "not lower it), and where it is above, SHORT says what it reaches (exit 3)",
    )
    parser.add_argument("--csv", metavar="OUT.csv", help="write the plan (t, voltage, segment)")
    parser.add_argument("--json", metavar="OUT.json", help="write the plan's summary as JSON")
    parser.add_argument(
        "--pretest",
        metavar="OUT.csv",
        help="write the automatic pre-test (at most 2 s, sized from MOTOR) instead of a plan",
    )
    parser.add_argument("--rate-hz", type=float, default=1000.0, help="driver sample rate (1000)")
    g = parser.add_argument_group("limits (default: the motor file's; aborts at 90 %)")
    g.add_argument("--voltage-max", type=float, default=None, metavar="V")
    g.add_argument("--current-max", type=float, default=None, metavar="A")
    g.add_argument("--speed-max", type=float, default=None, metavar="RAD_S")
    g.add_argument(
        "--heat-a2s",
        type=float,
        default=None,
        help="winding heat budget, int i^2 dt in A^2*s (default: the default sequence's)",
    )
    g.add_argument(
        "--budget-s",
        type=float,
        default=None,
        help="most motor time, s (default: the default sequence's length)",
    )
    g.add_argument(
        "--use-fraction",
        type=float,
        default=0.8,
        help="share of the current and speed aborts the plan may reach on the prior (0.8)",
    )
    g.add_argument(
        "--safe-mode",
        choices=("zero", "open"),
        default="zero",
        help="the session's safe state (stops must end inside the travel range)",
    )
    s = parser.add_argument_group("the rig's noise (default: the motor file's sensors)")
    s.add_argument("--current-noise", type=float, default=None, metavar="A")
    s.add_argument("--speed-noise", type=float, default=None, metavar="RAD_S")
    s.add_argument("--counts-per-rev", type=float, default=None, metavar="N")
    s.add_argument(
        "--current-lag-us",
        type=float,
        default=None,
        metavar="US",
        help="how late the current reading may be, at most (anti-alias filter, ADC timing): "
        "it biases L by up to lag / (L/R), counted in L's predicted sd (default: "
        "1/(2 pi) of a sample, a first-order filter at the sample rate; 0: none)",
    )
    parser.add_argument(
        "--criterion",
        choices=("A", "D"),
        default="A",
        help="A: sum of relative variances over their targets (default); D: log-determinant",
    )
    parser.add_argument(
        "--fix",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a parameter known and held in the fit (as identify --fix); repeatable",
    )
    parser.add_argument(
        "--compare",
        action="store_true",
        help="also predict the default sequence and WPILib's routine on the same prior",
    )


def _prior(args: argparse.Namespace, fixed: dict[str, float], dt: float):  # type: ignore[no-untyped-def]
    from dataclasses import replace

    from pmdc_ident.core.design import Prior
    from pmdc_ident.core.motors import BUILTIN_MOTORS, Limits, MotorSpec, load_motor

    src = Path(args.motor)
    is_data = args.motor not in BUILTIN_MOTORS and (
        src.is_dir() or src.suffix.lower() in _DATA_SUFFIXES
    )
    if not is_data:
        spec = load_motor(args.motor)
    else:
        spec = _identified(args, fixed)
    if fixed:
        known = {k: v for k, v in fixed.items() if k in ("R", "L", "Ke", "Kt", "J", "B")}
        if known:
            spec = replace(
                spec, model=replace(spec.model, params=spec.model.params.replace(**known))
            )
    lim = spec.limits
    limits = Limits(
        args.voltage_max or lim.voltage_max_v,
        args.current_max or lim.current_max_a,
        args.speed_max or lim.speed_max_rad_s,
    )
    prior = Prior.from_spec(
        MotorSpec(spec.name, spec.model, spec.sensors, limits, spec.description),
        current_noise_a=args.current_noise,
        speed_noise_rad_s=args.speed_noise,
        counts_per_rev=args.counts_per_rev,
        source=("pre-test " if is_data else "motor ") + str(args.motor),
    )
    if args.current_lag_us is not None:
        lag = 1e-6 * args.current_lag_us
        prior = replace(prior, noise=replace(prior.noise, current_lag_s=lag))
    return prior, limits


def _identified(args: argparse.Namespace, fixed: dict[str, float]):  # type: ignore[no-untyped-def]
    """The motor identified from a recorded pre-test (identify's pipeline)."""
    from pmdc_ident.core.estimators.output_error import CLOSURE_KT_KE
    from pmdc_ident.core.identification.identify import identify, merge_runs
    from pmdc_ident.dataio.units import load_input

    # read as identify reads it: its sidecar's units and columns apply
    run = load_input(args.motor).run
    result = identify(
        merge_runs([run]), fixed=fixed, closure=CLOSURE_KT_KE, holdout=False, frequency=False
    )
    spec = result.motor_spec(Path(args.motor).stem)
    noise = result.noise
    if "speed" not in noise and args.speed_noise is None and args.counts_per_rev is None:
        # the fit used the position: its noise level stands for the encoder's quantum
        pos = float(noise.get("position", 0.0))
        if pos > 0:
            args.counts_per_rev = 2.0 * math.pi / (pos * math.sqrt(12.0))
    print(f"prior identified from {args.motor}: model {result.model_kind}", file=sys.stderr)
    return spec


def run(args: argparse.Namespace) -> int:
    from pmdc_ident.commands._bounds import Bound, check_bounds
    from pmdc_ident.commands.outputs import check_distinct, check_file_output
    from pmdc_ident.core.design import parse_target, plan_csv_text, plan_experiment, session_limits
    from pmdc_ident.core.enums import SafeMode
    from pmdc_ident.core.fixed import parse_fix
    from pmdc_ident.core.safe_write import write_text  # atomic; never over what was read
    from pmdc_ident.core.safety import COMMAND_DELAY_S

    if not (math.isfinite(args.rate_hz) and 0 < args.rate_hz <= 1e6):
        msg = f"--rate-hz must lie in (0, 1e6], got {args.rate_hz}"
        raise ParameterError(msg)
    # one line before any work: a negative margin let the plan run past the travel range
    check_bounds(
        [
            (Bound("--start-rad", -1e9, 1e9, "the joint's angle at the start"), args.start_rad),
            (
                Bound("--travel-margin-rad", 0.0, 1e9, "kept from each end of the travel"),
                args.travel_margin_rad,
            ),
            (
                Bound("--command-delay", 0.0, 5.0, "how late a command may reach the motor, s"),
                args.command_delay,
            ),
            (Bound("--current-noise", 0.0, 1e6, "the current's sd, A"), args.current_noise),
            (Bound("--speed-noise", 0.0, 1e9, "the speed's sd, rad/s"), args.speed_noise),
            (
                Bound("--current-lag-us", 0.0, 1e6, "the current reading's lag, us"),
                args.current_lag_us,
            ),
            (
                Bound(
                    "--counts-per-rev", 0.0, 1e12, "encoder counts per revolution", open_low=True
                ),
                args.counts_per_rev,
            ),
        ]
    )
    for name in ("voltage_max", "current_max", "speed_max", "heat_a2s", "budget_s"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0):
            msg = f"--{name.replace('_', '-')} must be a positive number, got {v}"
            raise ParameterError(msg)
    inputs = [args.motor] if Path(args.motor).exists() else []
    targets = {
        "--csv": check_file_output("--csv", args.csv, inputs, suffixes=(".csv",), stdout_ok=False),
        "--json": check_file_output("--json", args.json, inputs, suffixes=(".json",)),
        "--pretest": check_file_output(
            "--pretest", args.pretest, inputs, suffixes=(".csv",), stdout_ok=False
        ),
    }
    check_distinct(targets)
    if args.pretest and (args.csv or args.reveal):
        msg = "--pretest writes the pre-test alone: drop --csv and --reveal"
        raise ParameterError(msg)
    fixed = parse_fix(args.fix)
    target = parse_target(args.target) if args.target is not None else None
    reveal = tuple(e.strip() for e in args.reveal.split(",") if e.strip())
    reveal_sizes = _parse_sizes(args.reveal_size, reveal)
    dt = 1.0 / args.rate_hz
    prior, driver = _prior(args, fixed, dt)
    travel = tuple(args.travel_rad) if args.travel_rad else None
    limits = session_limits(
        prior,
        driver,
        dt,
        travel_rad=travel,  # type: ignore[arg-type]
        start_rad=args.start_rad,
        heat_a2s=args.heat_a2s,
        budget_s=args.budget_s,
        use_fraction=args.use_fraction,
        safe_mode=SafeMode(args.safe_mode),
        travel_margin_rad=args.travel_margin_rad,
        command_delay_s=COMMAND_DELAY_S if args.command_delay is None else args.command_delay,
    )
    if args.pretest:
        from pmdc_ident.core.design.pretest import pretest_plan

        plan = pretest_plan(prior, limits, dt)
        text = plan_csv_text(
            plan, [f"pmdc-ident plan --pretest for {args.motor} at {args.rate_hz:g} Hz"]
        )
        write_text(Path(targets["--pretest"]), text, option="--pretest")
        print(
            f"pre-test: {len(plan.segments)} segments, {plan.duration_s:.3g} s "
            f"({', '.join(s.label for s in plan.segments)}); play it, log current and "
            f"position or speed, then `pmdc-ident plan LOG.csv ...` designs from it"
        )
        print(f"wrote {targets['--pretest']}")
        return 0
    fixed_names = tuple(n if n != "coulomb_friction.torque_nm" else "Tc" for n in fixed)
    designed = plan_experiment(
        prior,
        driver,
        dt,
        target=target,
        reveal=reveal,
        reveal_sizes=reveal_sizes,
        fixed=fixed_names,
        criterion=args.criterion,
        limits=limits,
    )
    for line in designed.summary_lines():
        print(line)
    doc: dict[str, Any] = designed.to_json()
    if args.compare:
        doc["compare"] = _compare(prior, limits, dt, designed)
    if reveal:
        doc["reveal"] = _reveal_limits(prior, designed, reveal)
    written = []
    if targets["--csv"] is not None:
        comments = [
            f"pmdc-ident plan for {args.motor} at {args.rate_hz:g} Hz: {len(designed.pieces)} "
            f"segments, {designed.duration_s:.4g} s",
            "predicted relative sd: "
            + ", ".join(f"{k} {v:.3g}" for k, v in doc["predicted_rsd"].items() if v is not None),
            "voltage empty = armature open; play one row per sample, log current and "
            "position or speed beside t and segment, then: pmdc-ident identify LOG.csv",
        ]
        path = Path(targets["--csv"])
        write_text(path, plan_csv_text(designed.plan, comments), option="--csv")
        written.append(path)
    if targets["--json"] is not None:
        text = json.dumps(doc, indent=2, allow_nan=False) + "\n"
        if targets["--json"] == "-":
            print(text, end="")
        else:
            path = Path(targets["--json"])
            write_text(path, text, option="--json")
            written.append(path)
    for p in written:
        print(f"wrote {p}")
    return 0 if designed.met else 3


def _parse_sizes(text: str, reveal: tuple[str, ...]) -> dict[str, float]:
    """``cogging=0.02,stribeck_friction=0.1`` -> sizes per revealed effect."""
    out: dict[str, float] = {}
    for item in text.split(","):
        if not item.strip():
            continue
        name, _, value = item.partition("=")
        name = name.strip()
        if name not in reveal:
            msg = f"--reveal-size {item.strip()!r}: {name!r} is not in --reveal"
            raise ParameterError(msg)
        try:
            size = float(value)
        except ValueError:
            size = math.nan
        if not (math.isfinite(size) and size > 0):
            msg = f"--reveal-size {item.strip()!r}: the size must be a positive number"
            raise ParameterError(msg)
        out[name] = size
    return out


def _reveal_limits(prior, designed, reveal) -> dict[str, Any]:  # type: ignore[no-untyped-def]
    """The smallest size of each revealed effect the planned record would show under the
    prior (diagnose's detection limits on a simulated run of the plan)."""
    from pmdc_ident.core.design.reveal import predicted_limits

    have = {d.effect: d for d in designed.reveal_limits}  # judged against --reveal-size
    rest = tuple(e for e in reveal if e not in have)
    more = {d.effect: d for d in predicted_limits(prior, designed.plan, rest)} if rest else {}
    limits = [have.get(e) or more[e] for e in reveal]
    print("shown on this plan (predicted, under the prior): the smallest sizes diagnose sees")
    for lim in limits:
        print(f"  {lim.text()}")
    return {lim.effect: lim.to_json() for lim in limits}


def _compare(prior, limits, dt, designed) -> dict[str, Any]:  # type: ignore[no-untyped-def]
    from pmdc_ident.core.design import evaluate_plan
    from pmdc_ident.core.design.baselines import default_sequence, wpilib_routine
    from pmdc_ident.core.design.target import public_name

    out: dict[str, Any] = {}
    print("compared on the same prior (predicted relative sd):")
    for name, plan in (
        ("default sequence", default_sequence(prior, limits, dt)),
        ("WPILib routine", wpilib_routine(prior, limits, dt)),
    ):
        rsd, _, _ = evaluate_plan(prior, plan)
        sds = ", ".join(
            f"{public_name(k)} {100 * v:.3g} %" if math.isfinite(v) else f"{public_name(k)} -"
            for k, v in rsd.items()
        )
        ratio = plan.duration_s / designed.duration_s if designed.duration_s > 0 else math.inf
        print(f"  {name}: {plan.duration_s:.4g} s ({ratio:.3g}x the plan): {sds}")
        out[name] = {
            "duration_s": plan.duration_s,
            "predicted_rsd": {
                public_name(k): (v if math.isfinite(v) else None) for k, v in rsd.items()
            },
        }
    return out
