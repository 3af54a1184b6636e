"""Every node parameter, declared once: name, type, default, range, description.

One table per node (:data:`DRIVER`, :data:`IDENTIFICATION`, :data:`RECORDER`,
:data:`MONITOR`) is the
only source of the parameters' defaults. The nodes declare them from it
(:func:`pmdc_ident.nodes.parameters.declare`), and the parameters files in
``config/`` and the parameter tables of ``docs/reference.md`` are generated from it::

    python -m pmdc_ident.process.parameter_tables --write   # rewrite them
    python -m pmdc_ident.process.parameter_tables --check   # exit 1 when they drifted

(``test/nodes/test_parameter_tables.py`` runs the check.) The identification node's
``sequence.*`` and ``steady_state.*`` entries take their defaults from the core
dataclasses :class:`~pmdc_ident.core.excitation.SequenceConfig` and
:class:`~pmdc_ident.node_logic.session.steady_state.SteadyStateConfig`.

This module does not import ROS, so the generator and its test run anywhere.

``safe_mode`` defaults differ on purpose: the driver opens the winding on its own
faults (0 V would brake a spinning rotor with a current up to Ke w / R, the very
current an over-current trip stops), while the identification node ends a session
with 0 V, which brings the rotor to rest for the next session; it opens the winding
where a test needs a coast-down.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator, Mapping
from dataclasses import MISSING, dataclass, fields
from pathlib import Path
from typing import Any

from pmdc_ident.core.excitation import SequenceConfig
from pmdc_ident.node_logic.session.steady_state import SteadyStateConfig

__all__ = [
    "DRIVER",
    "IDENTIFICATION",
    "MONITOR",
    "RECORDER",
    "TABLES",
    "NodeParameter",
    "ParameterTable",
    "markdown_table",
    "yaml_text",
]


@dataclass(frozen=True)
class NodeParameter:
    """One parameter. Its type is the default's (bool, int, float, str or a list)."""

    name: str
    default: Any
    description: str
    lower: float | None = None
    upper: float | None = None
    choices: tuple[str, ...] = ()
    runtime: bool = False  # may change while the node runs (else read-only)

    @property
    def type_name(self) -> str:
        d = self.default
        if isinstance(d, list):
            inner = type(d[0]).__name__ if d else "str"
            return f"{inner}[]"
        return type(d).__name__

    def refusal(self, value: Any) -> str:
        """Why ``value`` is refused ('' when it is fine): range and choices."""
        if self.choices and value not in self.choices:
            return f"parameter {self.name} must be one of {', '.join(self.choices)}, got {value!r}"
        numeric = isinstance(value, int | float) and not isinstance(value, bool)
        if numeric and self.lower is not None and self.upper is not None:
            if not self.lower <= value <= self.upper:
                return (
                    f"parameter {self.name} must lie in [{self.lower:g}, {self.upper:g}], "
                    f"got {value:g}"
                )
        return ""


@dataclass(frozen=True)
class ParameterTable:
    """A node's parameters; ``config`` is its parameters file under ``config/``."""

    node: str
    config: str
    header: str
    entries: tuple[NodeParameter, ...]

    def __iter__(self) -> Iterator[NodeParameter]:
        return iter(self.entries)

    def __getitem__(self, name: str) -> NodeParameter:
        for p in self.entries:
            if p.name == name:
                return p
        raise KeyError(name)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.entries)

    def defaults(self) -> dict[str, Any]:
        return {p.name: p.default for p in self.entries}


P = NodeParameter

# fmt: off
DRIVER = ParameterTable(
    node="driver_node",
    config="driver.yaml",
    header=(
        "Motor driver node (pmdc_ident/nodes/driver_node.py). Units are in the names.\n"
        "Start-time parameters are read-only while running; voltage_limit_v,\n"
        "current_limit_a, speed_limit_rad_s and watchdog_s can be changed at runtime\n"
        "(`ros2 param set`); bad values are refused with a reason."
    ),
    entries=(
        P("backend", "sim", "motor backend: 'sim' (simulated plant) or 'serial' (board)",
          choices=("sim", "serial")),
        P("motor", "seed000_ebike", "built-in motor name or path to a motor YAML file"),
        P("rate_hz", 1000.0, "sample rate of the driver, Hz", 1.0, 20000.0),
        P("poll_rate_hz", 250.0, "how often the backend is polled and due samples published, Hz",
          10.0, 2000.0),
        P("voltage_limit_v", 0.0,
          "commands are clamped to +-this, V (0 = the motor's limit, never above it)",
          0.0, 10000.0, runtime=True),
        P("current_limit_a", 0.0,
          "trip to safe (latched) above this |current|, A (0 = the motor's limit)",
          0.0, 100000.0, runtime=True),
        P("speed_limit_rad_s", 0.0,
          "trip to safe (latched) above this |speed|, rad/s (0 = the motor's limit)",
          0.0, 100000.0, runtime=True),
        P("watchdog_s", 1.5, "open the armature if no voltage_cmd came for this long, s (0 = "
          "off, at start only: never switched off at run time)", 0.0, 60.0, runtime=True),
        P("stop_wait_s", 6.0, "on Ctrl-C/SIGTERM: hold 0 V while a node still commands this "
          "driver (its own safe state first), at most this long, then the safe mode, s "
          "(below ros2 launch's 10 s before SIGKILL)", 0.0, 60.0),
        P("safe_mode", "open",
          "safe state on faults and exit: 'open' (disconnect the winding) or 'zero' (0 V, "
          "brakes)", choices=("open", "zero")),
        P("seed", 0, "sim: seed of the measurement noise", 0, 2**31 - 1),
        P("current_noise_a", -1.0, "sim: current noise std, A (negative = the motor file's)",
          -1.0, 1000.0),
        P("speed_noise_rad_s", -1.0, "sim: speed noise std, rad/s (negative = the motor file's)",
          -1.0, 10000.0),
        P("encoder_counts_per_rev", -1.0,
          "sim: encoder counts per turn (0 = exact, negative = the motor file's)", -1.0, 1e9),
        P("joint_name", "motor_joint", "joint name in the sample topics' JointState (the "
          "exports' joint: export-model --joint)"),
        P("hardware_id", "", "/diagnostics hardware_id ('' = pmdc_motor<namespace>, shared "
          "with the monitor of this motor)"),
        P("port", "/dev/ttyACM0", "serial: port of the driver board"),
        P("baud", 115200, "serial: baud rate", 1200, 10000000),
    ),
)
# fmt: on

_SEQUENCE_TEXT = {
    "staircase": "run the staircase (steady levels: R, Ke, friction)",
    "steps": "run the voltage steps",
    "sweep": "run the log chirp (frequency response)",
    "coast": "run the coast-down with the armature open (J, friction)",
    "staircase_levels": "staircase levels",
    "staircase_max_fraction": "top staircase level, fraction of voltage_max_v",
    "staircase_hold_tau": "nominal hold per level, tau_m (the real one waits for steady state)",
    "step_fraction": "step height, fraction of voltage_max_v",
    "step_hold_tau": "hold after each step, tau_m",
    "step_directions": "step directions (1 up, -1 down)",
    "sweep_offset_fraction": "chirp offset, fraction of voltage_max_v",
    "sweep_amplitude_fraction": "chirp amplitude, fraction of voltage_max_v",
    "sweep_duration_tau": "chirp length, tau_m",
    "sweep_f_low_per_tau": "chirp start frequency x tau_m",
    "sweep_f_high_hz": "chirp end frequency, Hz (0 = a quarter of the sample rate)",
    "coast_fraction": "spin-up voltage before the coast-down, fraction of voltage_max_v",
    "coast_spinup_tau": "spin-up time, tau_m",
    "coast_open_s": "armature open for this long, s (0 = the estimated stopping time)",
}
_STEADY_TEXT = {
    "window_s": "trailing window of the steady-state test, s (0 = one tau_m)",
    "n_sigma": "settled: drift within n_sigma x the noise ...",
    "rel_tol": "... or within this fraction of the mean",
    "min_hold_fraction": "hold a level at least this fraction of its nominal length",
    "timeout_factor": "give up waiting after this x the nominal hold",
    "check_every_s": "test for steady state this often, s",
}


def _from_dataclass(prefix: str, cls: type, text: Mapping[str, str]) -> tuple[NodeParameter, ...]:
    """Entries for a core config dataclass, defaults from the dataclass itself."""
    out = []
    for f in fields(cls):
        default = f.default if f.default is not MISSING else f.default_factory()  # type: ignore[misc]
        if isinstance(default, tuple):
            default = list(default)
        out.append(P(prefix + f.name, default, text[f.name]))
    return tuple(out)


# fmt: off
IDENTIFICATION = ParameterTable(
    node="identification_node",
    config="identification.yaml",
    header=(
        "Identification node (pmdc_ident/nodes/identification_node.py). Voltage fractions\n"
        "refer to voltage_max_v (0 = the driver's voltage limit); durations are multiples of\n"
        "the nominal motor's mechanical time constant tau_m (or of tau_m_s when set)."
    ),
    entries=(
        P("motor", DRIVER["motor"].default,
          "nominal motor sizing the plan (built-in name or YAML path)"),
        P("tau_m_s", 0.0, "rough mechanical time constant, s (0 = the nominal motor's)",
          0.0, 1000.0),
        P("rate_hz", 0.0, "driver sample rate, Hz (0 = read from the driver)", 0.0, 20000.0),
        P("driver_node", "driver_node", "driver node name (its limits are read before anything "
          "moves)"),
        P("driver_wait_s", 20.0, "how long to wait for the driver, s", 0.1, 600.0),
        P("voltage_max_v", 0.0, "voltage the fractions refer to, V (0 = the driver's limit)",
          0.0, 10000.0),
        P("safe_mode", "zero", "safe state on abort and end: 'zero' (0 V: brings the rotor to "
          "rest) or 'open' (armature open)", choices=("open", "zero")),
        P("safety.current_max_a", 0.0, "abort above this |current|, A (0 = 90 % of the "
          "driver's)", 0.0, 1e5),
        P("safety.speed_max_rad_s", 0.0, "abort above this |speed|, rad/s (0 = 90 % of the "
          "driver's)", 0.0, 1e6),
        P("safety.stall_current_a", 0.0, "stall: |current| above this, A (0 = half the "
          "current abort)", 0.0, 1e5),
        P("safety.stall_speed_rad_s", 1.0, "stall: while |speed| below this, rad/s", 0.0, 1e4),
        P("safety.stall_time_s", 0.0, "stall: for this long, s (0 = 3 tau_m)", 0.0, 60.0),
        P("safety.data_timeout_s", 3.0, "abort when no driver sample came for this long, s",
          0.01, 60.0),
        P("max_start_latency_s", 0.05, "start only once driver samples arrive within this of "
          "their stamp, s", 0.001, 10.0),
        P("settle_s", 0.3, "driver samples must arrive on time this long before a start, s",
          0.0, 60.0),
        P("confirm_timeout_s", 3.0, "after an abort, resend the safe command until the driver "
          "reports it, s", 0.1, 60.0),
        P("require_recorder", True, "wait for the recorder and abort if it disappears"),
        P("peer_timeout_s", 1.5, "recorder heartbeat timeout, s", 0.1, 60.0),
        P("autostart", True, "start a session as soon as the driver is up (else call "
          "run_session)"),
        P("exit_when_done", False, "exit after one session (bring-up uses this)"),
        P("output_dir", "pmdc_sessions", "where results go when no recorder names a bag"),
        P("fix", [""], "identification: fixed values NAME=VALUE (as pmdc-ident identify --fix)"),
        P("session_name", "", "name of the next session (default: session_<UTC time>_"
          "<namespace>_<6 hex digits>, unique)"),
        P("export_models", False, "also write the identified motor for MuJoCo (MJCF), URDF, "
          "ros2_control and its controller gains beside the bag (identified.*)"),
        P("export_reduction", 1.0, "exports: gear ratio, motor turns per joint turn",
          1e-6, 1e6),
        P("export_speed_bandwidth_hz", 0.0, "exports: speed-loop crossover of the gains, Hz "
          "(0 = a tenth of the current loop's)", 0.0, 1e5),
        P("export_phase_margin_deg", 60.0, "exports: phase margin of both loops, deg",
          20.0, 85.0),
        P("plan", "default", "which plan: 'default' (the sequence below), 'auto' (a pre-test, "
          "then a designed plan, re-fitted until the target is met) or a plan CSV "
          "(pmdc-ident plan --csv)"),
        P("plan_target", "", "auto: relative sd per parameter, e.g. R=1%,Tc=5%,L=off (empty: "
          "R, L, Ke, J, B 1 %, Tc 5 %)"),
        P("plan_travel_rad", [0.0, 0.0], "[MIN, MAX] travel of the joint in the encoder's frame, "
          "rad: plans stay inside, the session aborts outside ([0, 0]: no limit)"),
        P("plan_command_delay_s", 0.15, "travel: plans keep the joint inside when a command "
          "(a stop, a switch) reaches the driver this late, s (a host held up longer may "
          "carry it farther: the session then aborts)", 0.0, 5.0),
        P("plan_current_lag_s", -1.0, "auto: how late the current reading may be (anti-alias "
          "filter, ADC timing), s: it biases L by up to lag / (L/R), counted in L's predicted "
          "sd (negative = not known: 1/(2 pi) of a sample; 0 = none)", -1.0, 1.0),
        P("plan_budget_s", 0.0, "auto: most motor time, s (0 = the default sequence's length)",
          0.0, 1e5),
        P("plan_heat_a2s", 0.0, "auto: winding heat budget int i^2 dt, A^2*s (0 = the default "
          "sequence's)", 0.0, 1e9),
        P("plan_reveal", "", "auto: effects to make visible first, e.g. "
          "cogging,stribeck_friction"),
        *_from_dataclass("sequence.", SequenceConfig, _SEQUENCE_TEXT),
        *_from_dataclass("steady_state.", SteadyStateConfig, _STEADY_TEXT),
    ),
)
# fmt: on

# fmt: off
RECORDER = ParameterTable(
    node="recorder_node",
    config="recorder.yaml",
    header="Recorder node (pmdc_ident/nodes/recorder_node.py): one rosbag2/MCAP bag per session.",
    entries=(
        P("output_dir", "pmdc_sessions", "folder the session bags go into "
          "(<output_dir>/<session>/)"),
        P("rate_hz", 1000.0, "driver sample rate, Hz (sizes the queues and the ring)",
          0.0, 20000.0),
        P("margin_s", 0.0, "also keep driver samples this long before/after a session, s",
          0.0, 20000.0),
        # As long as the DDS sample queues (nodes/qos.py SAMPLE_BUFFER_S): a start marker
        # lost once is sent again at the writer's next heartbeat (Fast DDS: 3 s), and on
        # a loaded host came 4.05 s after its samples, beyond a 3 s ring (49 samples lost)
        P("ring_s", 10.0, "driver samples kept while no bag is open (a late start "
          "marker finds its samples here), s", 0.0, 20000.0),
        P("hold_s", 2.0, "samples wait this long before being written (late end marker), s",
          0.0, 20000.0),
    ),
)
# fmt: on

# fmt: off
MONITOR = ParameterTable(
    node="monitor_node",
    config="monitor.yaml",
    header="Drift monitor node (pmdc_ident/nodes/monitor_node.py).",
    entries=(
        P("params", DRIVER["motor"].default,
          "identified motor YAML (`identify --yaml`) or built-in name"),
        P("rate_hz", 1000.0, "driver sample rate, Hz (sizes the subscription queues)", 1.0, 1e5),
        P("process_period_s", 0.02, "samples are fed to the monitor this often, s", 0.001, 1.0),
        P("report_period_s", 0.1, "model_drift publishing period, s", 0.01, 10.0),
        P("diagnostics_period_s", 1.0, "/diagnostics publishing period, s", 0.05, 60.0),
        P("r_warn_rel", 0.10, "R rise for WARN, relative to the identified R", 0.0, 10.0),
        P("r_error_rel", 0.20, "R rise for ERROR, relative", 0.0, 10.0),
        P("ke_warn_rel", 0.05, "Ke change for WARN, relative", 0.0, 1.0),
        P("ke_error_rel", 0.10, "Ke change for ERROR, relative", 0.0, 1.0),
        P("friction_warn_nm", 0.0, "friction rise for WARN, N*m (0: identified friction)",
          0.0, 1e4),
        P("friction_error_nm", 0.0, "friction rise for ERROR, N*m (0: 3x the WARN step)",
          0.0, 1e4),
        P("delay_warn_s", 0.002, "delay change for WARN, s", 0.0, 1.0),
        P("delay_error_s", 0.010, "delay change for ERROR, s", 0.0, 1.0),
        P("hold_s", 1.0, "a higher level must be proven again this much later, s", 0.01, 600.0),
        P("suggest_after_s", 30.0, "WARN this long latches the re-identify suggestion, s",
          0.1, 1e5),
        P("stale_s", 2.0, "no driver sample for this long: /diagnostics says STALE, s",
          0.01, 600.0),
        P("hardware_id", "", "/diagnostics hardware_id ('' = pmdc_motor<namespace>, shared "
          "with this motor's driver)"),
    ),
)
# fmt: on

TABLES: tuple[ParameterTable, ...] = (DRIVER, IDENTIFICATION, RECORDER, MONITOR)


# ---------------------------------------------------------------------------
# Generated files
# ---------------------------------------------------------------------------
def _yaml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, list):
        return "[" + ", ".join(_yaml_value(x) for x in v) + "]"
    if isinstance(v, str):
        return '""' if v == "" else v
    return repr(v)


def yaml_text(table: ParameterTable) -> str:
    """The node's parameters file: every default, keyed ``/**`` so it reaches the node
    under any name and namespace; nested keys for dotted names."""
    head = "".join(f"# {line}\n" for line in table.header.splitlines())
    lines = [
        head + "# Generated from pmdc_ident/process/parameter_tables.py (edit the table there,\n"
        "# then: python -m pmdc_ident.process.parameter_tables --write).",
        "/**:",
        "  ros__parameters:",
    ]
    group = ""
    for p in table:
        prefix, _, leaf = p.name.rpartition(".")
        if prefix != group:
            if prefix:
                lines.append(f"    {prefix}:")
            group = prefix
        indent = "      " if prefix else "    "
        item = f"{indent}{leaf}: {_yaml_value(p.default)}"
        lines.append(f"{item:<40} # {p.description}")
    return "\n".join(lines) + "\n"


def _range(p: NodeParameter) -> str:
    if p.choices:
        return " / ".join(f"`{c}`" for c in p.choices)
    if p.lower is not None and p.upper is not None:
        return f"{p.lower:g} .. {p.upper:g}"
    return ""


def markdown_table(table: ParameterTable) -> str:
    """The reference's table of the node's parameters (``docs/reference.md``)."""
    rows = [
        "| parameter | type | default | range | meaning |",
        "| --- | --- | --- | --- | --- |",
    ]
    for p in table:
        meaning = p.description.replace("|", "\\|") + (" (runtime)" if p.runtime else "")
        rows.append(
            f"| `{p.name}` | {p.type_name} | `{_yaml_value(p.default)}` | {_range(p)} "
            f"| {meaning} |"
        )
    return "\n".join(rows) + "\n"


def _markers(table: ParameterTable) -> tuple[str, str]:
    return (
        f"<!-- parameters {table.node}: generated by python -m "
        "pmdc_ident.process.parameter_tables --write -->\n",
        f"<!-- end parameters {table.node} -->\n",
    )


def readme_with_tables(text: str) -> str:
    """``text`` (``docs/reference.md``) with every node's generated table between its markers."""
    for table in TABLES:
        begin, end = _markers(table)
        i, j = text.find(begin), text.find(end)
        if i < 0 or j < i:
            msg = (
                f"docs/reference.md has no markers for {table.node}: "
                f"{begin.strip()} ... {end.strip()}"
            )
            raise ValueError(msg)
        text = text[: i + len(begin)] + markdown_table(table) + text[j:]
    return text


def generated_files(repo: Path) -> dict[Path, str]:
    """Every generated file's path and wanted content."""
    out = {repo / "config" / t.config: yaml_text(t) for t in TABLES}
    reference = repo / "docs" / "reference.md"
    out[reference] = readme_with_tables(reference.read_text(encoding="utf-8"))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="rewrite the generated files")
    ap.add_argument("--check", action="store_true", help="exit 1 if a generated file drifted")
    ap.add_argument("--repo", type=Path, default=Path(__file__).resolve().parents[2])
    args = ap.parse_args(argv)
    stale = []
    for path, text in generated_files(args.repo).items():
        if path.is_file() and path.read_text(encoding="utf-8") == text:
            continue
        stale.append(path)
        if args.write:
            from pmdc_ident.core.safe_write import write_text

            write_text(path, text)  # complete under its name, or not there
    for path in stale:
        verb = "wrote" if args.write else "out of date:"
        print(f"{verb} {path.relative_to(args.repo)}")
    return 1 if stale and args.check else 0


if __name__ == "__main__":
    sys.exit(main())
