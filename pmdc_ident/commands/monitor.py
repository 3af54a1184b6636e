"""``pmdc-ident monitor DATA --params MOTOR.yaml``: replay a recording through the drift monitor.

The same :class:`~pmdc_ident.node_logic.drift_monitor.DriftMonitor` the monitor node
runs: every sample in time order (segments joined; a gap restarts the filters),
the drift printed over time, a summary, and with ``--report DIR`` a plot and a
CSV of the estimates with their 95 % intervals.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path
from typing import Any

from pmdc_ident.core.errors import DataError

# what --report DIR writes
REPORT_FILES = ("drift.csv", "drift.png")

HELP = "replay a bag or CSV through the drift monitor: R, temperature, Ke, friction, delay"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", metavar="DATA", help="a bag directory, an .mcap file or a CSV")
    parser.add_argument(
        "--params",
        required=True,
        metavar="MOTOR.yaml",
        help="the identified motor (`identify --yaml`), or a built-in motor name",
    )
    parser.add_argument("--report", metavar="DIR", help="write drift.png and drift.csv")
    parser.add_argument(
        "--every",
        type=float,
        default=None,
        metavar="S",
        help="print every S seconds (default: ~30 lines)",
    )
    parser.add_argument("--r-warn", type=float, default=0.10, help="R rise for WARN (relative)")
    parser.add_argument("--r-error", type=float, default=0.20, help="R rise for ERROR (relative)")
    parser.add_argument(
        "--ke-warn", type=float, default=0.05, help="Ke change for WARN (relative)"
    )
    parser.add_argument("--ke-error", type=float, default=0.10, help="Ke change for ERROR")
    parser.add_argument(
        "--friction-warn", type=float, default=0.0, help="friction rise for WARN, N*m (0: auto)"
    )
    parser.add_argument(
        "--friction-error", type=float, default=0.0, help="friction rise for ERROR, N*m (0: auto)"
    )
    parser.add_argument("--delay-warn", type=float, default=0.002, help="delay change for WARN, s")
    parser.add_argument(
        "--delay-error", type=float, default=0.010, help="delay change for ERROR, s"
    )


def run(args: argparse.Namespace) -> int:
    from pmdc_ident.commands._bounds import Bound, check_bounds
    from pmdc_ident.commands.outputs import check_folder_output
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.dataio.units import load_input
    from pmdc_ident.node_logic.drift_monitor import DriftMonitor, MonitorConfig

    check_bounds(
        [
            (
                Bound("--every", 0.0, 1e9, "seconds between printed lines", open_low=True),
                args.every,
            ),
            *(
                (
                    Bound(f"--{name.replace('_', '-')}", 0.0, 1e6, "a drift threshold"),
                    getattr(args, name),
                )
                for name in (
                    "r_warn",
                    "r_error",
                    "ke_warn",
                    "ke_error",
                    "friction_warn",
                    "friction_error",
                    "delay_warn",
                    "delay_error",
                )
            ),
        ]
    )
    args.report = check_folder_output(
        "--report", args.report, [args.data, args.params], writes=REPORT_FILES
    )

    spec = load_motor(args.params)
    # read as identify and diagnose read it (units sidecar, the assumption register's
    # continuity: a separate run restarts the filters, as a gap in time does)
    data = load_input(args.data).run
    t, v, i, w = _samples(data)
    starts = _run_starts(data, t)
    cfg = MonitorConfig(
        r_warn_rel=args.r_warn,
        r_error_rel=args.r_error,
        ke_warn_rel=args.ke_warn,
        ke_error_rel=args.ke_error,
        friction_warn_nm=args.friction_warn,
        friction_error_nm=args.friction_error,
        delay_warn_s=args.delay_warn,
        delay_error_s=args.delay_error,
    )
    mon = DriftMonitor(spec, cfg)
    reports = []
    bounds = [0, *starts, t.size]
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        if k:
            mon.restart_filters()
        reports += mon.process(t[a:b], v[a:b], i[a:b], w[a:b])
    if starts:
        print(f"{len(starts)} separate run(s) in {args.data}: the filters restart at each")
    if not reports:
        msg = f"{args.data}: too short to monitor ({t.size} samples over {t[-1] - t[0]:.3g} s)"
        raise DataError(msg)
    every = args.every or max((t[-1] - t[0]) / 30.0, cfg.report_period_s)
    print(
        f"{'t s':>8} {'R ohm':>16} {'dT K':>12} {'Ke V*s/rad':>20} {'friction N*m':>18} "
        f"{'delay ms':>13}  level"
    )
    next_t = -math.inf
    for r in reports:
        if r.t_s >= next_t or r is reports[-1]:
            next_t = r.t_s + every
            print(_line(r))
    last = reports[-1]
    levels = [r.level for r in reports]
    print(f"worst level {max(levels).name}; now {last.level.name}: {last.message}")
    if args.report:
        _write_report(args.report, reports)
        print(f"{args.report}: drift.png, drift.csv")
    return 0


def _samples(data: Any) -> tuple[Any, ...]:
    """All samples of a run in time order, with voltage, current and speed."""
    import numpy as np

    segs = sorted(data.segments, key=lambda s: float(s.t[0]))  # type: ignore[attr-defined]
    missing = [s.label for s in segs if s.voltage is None or s.current is None]
    if missing:
        msg = f"the monitor needs voltage and current; segment {missing[0]!r} lacks one"
        raise DataError(msg)
    cols = [
        np.concatenate([getattr(s, name) for s in segs]) for name in ("t", "voltage", "current")
    ]
    w = np.concatenate([s.speed_or_derivative() for s in segs])
    order = np.argsort(cols[0], kind="stable")
    return tuple(c[order] for c in (*cols, w))


def _run_starts(data: Any, t: Any) -> list[int]:
    """Sample indices (into the time-ordered samples) where a separate run starts: a
    segment on the same clock as the one before that does not continue it."""
    import numpy as np

    from pmdc_ident.core.assumptions import continues
    from pmdc_ident.core.data import same_clock

    segs = sorted(data.segments, key=lambda s: float(s.t[0]))
    starts = [
        int(np.searchsorted(t, s.t[0]))
        for prev, s in zip(segs[:-1], segs[1:], strict=True)
        if same_clock(prev, s) and not continues(s)
    ]
    return sorted(set(starts))


def _pm(q: object, scale: float = 1.0, fmt: str = ".4g") -> str:
    return f"{q.value * scale:{fmt}}+-{q.ci95 * scale:.2g}"  # type: ignore[attr-defined]


def _line(r: object) -> str:
    q = {x.name: x for x in r.quantities}  # type: ignore[attr-defined]
    flag = " re-identify" if r.suggest_reidentify else ""  # type: ignore[attr-defined]
    return (
        f"{r.t_s:8.1f} {_pm(q['resistance']):>16} "  # type: ignore[attr-defined]
        f"{r.temperature_rise_k:+6.1f}+-{r.temperature_ci95_k:<4.2g} "  # type: ignore[attr-defined]
        f"{_pm(q['back_emf']):>20} {_pm(q['friction']):>18} "
        f"{_pm(q['delay'], 1e3, '.3f'):>13}  {r.level.name}{flag}"  # type: ignore[attr-defined]
    )


def _write_report(out: Path, reports: list) -> None:
    import numpy as np

    out.mkdir(parents=True, exist_ok=True)
    names = [q.name for q in reports[0].quantities]
    header = ["t_s", "level", "suggest_reidentify", "temperature_rise_k"]
    for n in names:
        header += [n, f"{n}_ci95"]
    rows = []
    for r in reports:
        row = [r.t_s, int(r.level), int(r.suggest_reidentify), r.temperature_rise_k]
        for q in r.quantities:
            row += [q.value, q.ci95]
        rows.append(row)
    arr = np.array(rows)
    from pmdc_ident.core.safe_write import atomic_path, save_figure

    with atomic_path(out / "drift.csv") as tmp:
        np.savetxt(tmp, arr, delimiter=",", header=",".join(header), comments="")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(names) + 1, 1, sharex=True, figsize=(9, 2.2 * (len(names) + 1)))
    t = arr[:, 0]
    for k, (ax, q0) in enumerate(zip(axes, reports[0].quantities, strict=False)):
        val, ci = arr[:, 4 + 2 * k], arr[:, 5 + 2 * k]
        ax.plot(t, val, lw=1)
        ax.fill_between(t, val - ci, val + ci, alpha=0.3, lw=0)
        for thr, style in ((q0.warn, "--"), (q0.error, ":")):
            ax.axhline(q0.reference + thr, color="k", ls=style, lw=0.8)
            if q0.name != "resistance" and q0.name != "friction":
                ax.axhline(q0.reference - thr, color="k", ls=style, lw=0.8)
        ax.set_ylabel(f"{q0.name}\n{q0.unit}")
    axes[-1].step(t, arr[:, 1], where="post")
    axes[-1].set_yticks([0, 1, 2], ["OK", "WARN", "ERROR"])
    axes[-1].set_xlabel("t s")
    fig.tight_layout()
    save_figure(fig, out / "drift.png", dpi=90)
    plt.close(fig)
