"""``pmdc-ident export-model``: the identified motor for MuJoCo, URDF, ros2_control, a drive."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.safe_write import write_text

HELP = (
    "write an identified motor as MuJoCo MJCF (--mujoco), URDF (--urdf), ros2_control "
    "parameters (--ros2-control) and/or cascade PI gains (--gains)"
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "motor", metavar="MOTOR", help="the YAML `identify --yaml` writes, or a built-in motor"
    )
    parser.add_argument("--mujoco", metavar="OUT.xml", help="write MuJoCo MJCF")
    parser.add_argument(
        "--diagnosis",
        metavar="DIAG.json",
        help="the JSON `pmdc-ident diagnose --json` wrote for this motor: the MJCF carries "
        "the diagnosis' model with every named effect MuJoCo can express (docs/mujoco.md)",
    )
    parser.add_argument(
        "--mujoco-actuator",
        choices=("auto", "dcmotor", "general"),
        default="auto",
        help="MuJoCo's DC motor actuator (MuJoCo >= 4) or a general actuator with the same "
        "torque-speed law (default: dcmotor unless an older mujoco is installed)",
    )
    parser.add_argument("--urdf", metavar="OUT.urdf", help="write a URDF joint")
    parser.add_argument("--ros2-control", metavar="OUT.yaml", help="write ros2_control parameters")
    parser.add_argument(
        "--gains", metavar="OUT.yaml", help="write PI current/speed gains and checks"
    )
    parser.add_argument("--joint", default="motor_joint", help="joint name (default motor_joint)")
    parser.add_argument(
        "--reduction", type=float, default=1.0, help="gear ratio, motor turns per joint turn"
    )
    parser.add_argument(
        "--sample-rate-hz", type=float, default=1000.0, help="controller rate (default 1000)"
    )
    parser.add_argument(
        "--speed-bandwidth-hz",
        type=float,
        default=None,
        help="speed-loop crossover (default: a tenth of the current loop's)",
    )
    parser.add_argument(
        "--current-bandwidth-hz",
        type=float,
        default=None,
        help="current-loop crossover (default: the fastest the margin and rate allow)",
    )
    parser.add_argument(
        "--phase-margin-deg", type=float, default=60.0, help="both loops (default 60)"
    )
    parser.add_argument(
        "--verify-on",
        metavar="MOTOR",
        default=None,
        help="also check the gains on this motor (a motor YAML with effects, or a built-in)",
    )


def run(args: argparse.Namespace) -> int:
    from pmdc_ident.core.motors import load_motor

    if not any((args.mujoco, args.urdf, args.ros2_control, args.gains)):
        msg = "nothing to write: give --mujoco, --urdf, --ros2-control and/or --gains"
        raise PmdcError(msg)
    if args.diagnosis and not args.mujoco:
        msg = "--diagnosis goes into the MuJoCo model: give --mujoco OUT.xml with it"
        raise PmdcError(msg)
    _check_numbers(args)
    _check_outputs(args)
    spec = load_motor(args.motor)
    if args.mujoco:
        from pmdc_ident.exports.mujoco_xml import mujoco_xml

        mj_spec = spec
        if args.diagnosis:
            from pmdc_ident.exports.diagnosis import load_diagnosis, motor_with_diagnosis

            diagnosed = motor_with_diagnosis(
                spec, load_diagnosis(args.diagnosis), source=str(args.diagnosis)
            )
            mj_spec = diagnosed.spec
            for line in diagnosed.lines:
                print(f"{args.diagnosis}: {line}")
        flavour = None if args.mujoco_actuator == "auto" else args.mujoco_actuator
        ex = mujoco_xml(mj_spec, reduction=args.reduction, joint=args.joint, flavour=flavour)
        ex.write(args.mujoco)
        print(f"{args.mujoco}: MJCF, {ex.flavour} actuator '{ex.actuator}' on '{ex.joint}'")
        for item in ex.carried:
            print(f"  carried: {item.split(': ', 1)[0]}")
        for item in ex.not_carried:
            print(f"  not carried: {item}")
    if args.urdf:
        from pmdc_ident.exports.urdf import urdf_xml

        write_text(args.urdf, urdf_xml(spec, reduction=args.reduction, joint=args.joint))
        print(f"{args.urdf}: URDF joint '{args.joint}' (reduction {args.reduction:g})")
    if args.gains or args.ros2_control:
        return _gains(args, spec)
    return 0


def _check_numbers(args: argparse.Namespace) -> None:
    """Every numeric option inside what a controller or a gear can be (one line each)."""
    from pmdc_ident.commands._bounds import Bound, check_bounds

    rate = args.sample_rate_hz
    nyquist = rate / 2 if isinstance(rate, float) and math.isfinite(rate) and rate > 0 else 1e9
    check_bounds(
        [
            (Bound("--sample-rate-hz", 1.0, 1e6, "a controller's loop rate, Hz"), rate),
            (
                Bound("--reduction", 0.0, 1e6, "motor turns per joint turn", open_low=True),
                args.reduction,
            ),
            (
                Bound("--phase-margin-deg", 10.0, 89.0, "a PI loop's phase margin"),
                args.phase_margin_deg,
            ),
            (
                Bound(
                    "--speed-bandwidth-hz",
                    0.0,
                    nyquist,
                    "below half the sample rate",
                    open_low=True,
                ),
                args.speed_bandwidth_hz,
            ),
            (
                Bound(
                    "--current-bandwidth-hz",
                    0.0,
                    nyquist,
                    "below half the sample rate",
                    open_low=True,
                ),
                args.current_bandwidth_hz,
            ),
        ]
    )


def _check_outputs(args: argparse.Namespace) -> None:
    """Every output path checked (and made a Path) before any work (see commands.outputs)."""
    from pmdc_ident.commands.outputs import check_distinct, check_file_output

    inputs = [x for x in (args.motor, args.verify_on, args.diagnosis) if x and Path(x).exists()]
    suffixes = {
        "mujoco": (".xml",),
        "urdf": (".urdf", ".xml"),
        "ros2_control": (".yaml", ".yml"),
        "gains": (".yaml", ".yml"),
    }
    targets = {}
    for dest, suffix in suffixes.items():
        option = "--" + dest.replace("_", "-")
        value = getattr(args, dest)
        path = check_file_output(option, value, inputs, suffixes=suffix, stdout_ok=False)
        setattr(args, dest, path)
        targets[option] = path
    check_distinct(targets)


def _gains(args: argparse.Namespace, spec: object) -> int:
    import yaml

    from pmdc_ident.core.control_design import TOLERANCES, check_gains, design_gains
    from pmdc_ident.core.motors import MotorSpec, load_motor

    assert isinstance(spec, MotorSpec)
    design = design_gains(
        spec.model.params,
        spec.limits,
        sample_rate_hz=args.sample_rate_hz,
        speed_bandwidth_hz=_speed_bandwidth(args),
        phase_margin_deg=args.phase_margin_deg,
        current_bandwidth_hz=args.current_bandwidth_hz,
    )
    others = [load_motor(args.verify_on)] if args.verify_on else []
    checks = check_gains(design, spec, others)
    if args.ros2_control:
        from pmdc_ident.exports.urdf import ros2_control_yaml

        text = ros2_control_yaml(spec, design, reduction=args.reduction, joint=args.joint)
        write_text(args.ros2_control, text)
        print(f"{args.ros2_control}: ros2_control parameters for '{args.joint}'")
    pr = design.promised
    print(
        f"current PI: Kp {design.current_kp_v_per_a:.4g} V/A, Ki {design.current_ki_v_per_as:.4g}"
        f" V/(A*s) ({design.current_crossover_hz:.3g} Hz, "
        f"{design.current_phase_margin_deg:.3g} deg margin)"
    )
    print(
        f"speed PI:   Kp {design.speed_kp_a_s_per_rad:.4g} A*s/rad, Ki "
        f"{design.speed_ki_a_per_rad:.4g} A/rad ({design.speed_crossover_hz:.3g} Hz, "
        f"{design.speed_phase_margin_deg:.3g} deg margin) at {design.sample_rate_hz:g} Hz"
    )
    print(
        f"promised {pr.step_rad_s:.3g} rad/s speed step: overshoot {pr.overshoot_pct:.1f} % "
        f"(<= {pr.overshoot_pct + TOLERANCES['overshoot_pp']:.1f}), settling {pr.settling_s:.3f} s"
        f" (<= {pr.settling_s * TOLERANCES['settling_factor']:.3f})"
    )
    for c in checks:
        m = c.measured
        verdict = "ok" if c.ok else "NOT MET"
        print(
            f"  closed loop on {c.plant}: overshoot {m.overshoot_pct:.1f} %, settling "
            f"{m.settling_s:.3f} s, peak {c.peak_current_a:.3g} A {c.peak_voltage_v:.3g} V: "
            f"{verdict}"
        )
    if args.gains:
        data = design.as_dict()
        data["verification"] = [
            {
                "plant": c.plant,
                "overshoot_pct": c.measured.overshoot_pct,
                "settling_2pct_s": c.measured.settling_s,
                "peak_current_a": c.peak_current_a,
                "peak_voltage_v": c.peak_voltage_v,
                "within_promise": c.ok,
            }
            for c in checks
        ]
        header = f"# Cascade PI gains written by pmdc-ident export-model for '{spec.name}'.\n"
        write_text(args.gains, header + yaml.safe_dump(data, sort_keys=False))
        print(f"{args.gains}: gains and closed-loop checks")
    return 0 if all(c.ok for c in checks) else 1


def _speed_bandwidth(args: argparse.Namespace) -> float:
    if args.speed_bandwidth_hz is not None:
        return float(args.speed_bandwidth_hz)
    from pmdc_ident.core.control_design import current_crossover_hz

    wc = current_crossover_hz(
        args.sample_rate_hz, args.phase_margin_deg, args.current_bandwidth_hz
    )
    return wc / 10.0
