"""The assumption register: every modelling assumption identification and diagnosis
make, the check on the data that tests it, and what the tool does when it fails.

Issue 22: the tool gave answers that looked certain on records whose shape it had
never met, because each command held assumptions it never tested on the data in
hand (and two commands could hold different ones about one file). This module is
the one place that owns them. ``docs/assumptions.md`` is :data:`REGISTER` in words,
with each assumption's test (a record that violates it), and a test checks the two
agree.

Every command reads data through the same checks:

* **data** stage (before any fit; ``check``, ``identify``, ``diagnose``, ``monitor``
  and the identification node): :func:`data_findings` adds the register's findings
  to the data-quality gate (``core/quality/gate.py``), and :func:`segment_reading`
  is how the segments were read (which one continues which), written into every
  command's JSON under ``assumptions_checked``, the same function for all;
* **fit** stage (``identify`` and the node, in ``core.identification.identify.identify``):
  the checks of :mod:`pmdc_ident.core.quality.misfit` flag every parameter that fails one;
* **diagnosis** stage: :func:`check_holdout` before the baseline is fitted.

A failed assumption either changes the treatment and says so in one line, or is
refused with exit status 2 and the fix (:class:`Treatment`).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from pmdc_ident.core.data import Run, Segment
    from pmdc_ident.core.quality.findings import Finding

__all__ = [
    "REGISTER",
    "Assumption",
    "Stage",
    "Treatment",
    "by_id",
    "check_holdout",
    "markdown_table",
    "continues",
    "data_findings",
    "register_json",
    "segment_reading",
]


class Stage(enum.Enum):
    DATA = "data"  # before any fit, every command
    FIT = "fit"  # identify's result (CLI and node)
    DIAGNOSIS = "diagnosis"  # diagnose's split


class Treatment(enum.Enum):
    CHANGE = "change"  # the treatment changes, one line says so
    REFUSE = "refuse"  # exit status 2, one line with the fix


@dataclass(frozen=True)
class Assumption:
    """One assumption: what is assumed, the data check, the treatment on failure, the
    finding code or flag that reports it, and the test whose record violates it."""

    id: str
    statement: str
    check: str
    treatment: Treatment
    on_failure: str
    stage: Stage
    codes: tuple[str, ...]
    test: str


_T = "test/core/test_foreign_corpus.py::"
_A = "test/core/test_assumptions.py::"

REGISTER: tuple[Assumption, ...] = (
    Assumption(
        "continuity",
        "a labelled segment that starts one sample period after the previous one ends "
        "continues it (the motor's state, the commands and the heat carry over)",
        "the clock (one period later, same period) and the samples: speed, current and "
        "position across the boundary change by no more than 1.5x the largest change "
        "between samples elsewhere in the record, plus 6 noise levels and one quantum",
        Treatment.CHANGE,
        "the segment is a separate run from its own first sample (no history, no "
        "lead-in), said once: `continuity` warning",
        Stage.DATA,
        ("continuity",),
        _T + "test_joined_runs_are_separate_runs_and_diagnose_as_with_gaps",
    ),
    Assumption(
        "position-restart",
        "in a log without labels, a drop of the position column is a wrap at one turn",
        "a drop onto 0 or the log's first value, with the rotor at rest after it, beyond "
        "what the position does between samples elsewhere, is a new run starting",
        Treatment.CHANGE,
        "the log is cut there into separate runs (`run.1`, `run.2`...), each cut into its "
        "experiments, no `position-wrap` error: `continuity` warning",
        Stage.DATA,
        ("continuity", "position-wrap"),
        _T + "test_a_position_that_restarts_with_each_run_is_not_a_wrap",
    ),
    Assumption(
        "uniform-clock",
        "samples come on a uniform clock",
        "intervals off the median period by more than 25 % (gaps) or 5 % (jitter)",
        Treatment.CHANGE,
        "a segment with gaps is fitted as its contiguous pieces, each from its own state, "
        "and the gate's checks read the same pieces (none compares samples across a gap); "
        "jitter: each segment simulated on its median period (`gaps`, `jitter` warnings)",
        Stage.DATA,
        ("gaps", "jitter"),
        "test/commands/test_record_shapes.py::"
        "test_dropped_samples_split_a_segment_into_pieces_that_are_fitted",
    ),
    Assumption(
        "units",
        "columns are in SI units (s, V, A, rad, rad/s) with the motor's signs",
        "time constants a motor has, speed against d(position)/dt, signs of R, Ke, Kt/J "
        "from the record, magnitudes",
        Treatment.REFUSE,
        "exit 2 naming the option (`--time-unit ms`, `--speed-unit rpm`, `--column "
        "current=-HEADER`...)",
        Stage.DATA,
        ("time-unit", "speed-position", "sign", "voltage-unit", "position-unit"),
        "test/core/quality/test_quality_gate.py::"
        "test_unit_slip_is_an_error_with_its_fix_and_the_fix_passes",
    ),
    Assumption(
        "current-amperes",
        "the current column is in amperes",
        "the current's 95th percentile against what the record's voltage and its own "
        "winding resistance (V/I regression) make plausible: a stall current V/R beyond "
        "2500 A with more than 200 A x max(1, V/12 V) drawn is milliamps",
        Treatment.REFUSE,
        "exit 2: `current-unit` error, fix `--current-unit mA` (a 48 V, 0.05 ohm traction "
        "motor drawing 205 A passes)",
        Stage.DATA,
        ("current-unit",),
        _T + "test_a_traction_motor_drawing_200_a_is_not_milliamps",
    ),
    Assumption(
        "speed-at-sample",
        "the speed column is the shaft speed at each sample",
        "a speed in whole encoder counts per sample without a position column is the "
        "counts' mean over the interval, half a sample late",
        Treatment.REFUSE,
        "exit 2: `speed-counts`, fix `--speed-averaged` (its running sum is read as the "
        "encoder's position)",
        Stage.DATA,
        ("speed-counts",),
        "test/commands/test_record_shapes.py::test_sample_rates_from_50_hz_to_20_khz",
    ),
    Assumption(
        "excitation",
        "the record carries information (the motor is driven and moves)",
        "the shared rule `core/data.excitation_problem`",
        Treatment.REFUSE,
        "exit 2: `no-excitation` with what to record",
        Stage.DATA,
        ("no-excitation", "no-drive"),
        "test/commands/test_fit_bad_inputs.py::test_a_record_without_information_is_one_line",
    ),
    Assumption(
        "armature-voltage",
        "the voltage column is the voltage at the armature, applied over the sample (no "
        "delay, no ramp) and the current sensor sees the armature current unfiltered",
        "the current's first response after each voltage edge (`delay`), an S-shaped rise "
        "(`current-filter`), power balance V*I against R*I^2 + L*I*dI/dt + Ke*w*I",
        Treatment.CHANGE,
        "L is flagged not identifiable with the finding's fix (what to record); R, Ke, J "
        "keep their values",
        Stage.DATA,
        ("delay", "current-filter", "power-balance"),
        "test/commands/test_record_shapes.py::"
        "test_a_filtered_current_sensor_flags_l_and_keeps_r_ke_j",
    ),
    Assumption(
        "run-start",
        "a run starts from the state its first samples show; the fit estimates it with "
        "the parameters",
        "where a run starts with the rotor measured at rest, the estimated start must "
        "agree with the first samples (speed within 4 noise levels + one quantum of the "
        "measured, current not of the wrong sign beyond 4 noise levels); when not, the "
        "fit is repeated without the run's first stretch",
        Treatment.CHANGE,
        "every parameter that moves beyond its interval without the start, or has no "
        "information left, is flagged: it rests on a start the data contradict",
        Stage.FIT,
        ("run-start",),
        _T + "test_a_start_from_rest_with_the_first_level_on_gives_a_model_export_accepts",
    ),
    Assumption(
        "white-residuals",
        "the model holds: what it leaves is white measurement noise, so the Cramer-Rao "
        "interval is the uncertainty",
        "whiteness of the current and speed residuals (autocorrelation inside the 95 % band)",
        Treatment.CHANGE,
        "intervals widened by the residuals' long-run variance factor, and every parameter "
        "must pass the misfit-robust checks below before it is reported identified",
        Stage.FIT,
        ("white-residuals",),
        _T + "test_a_speed_sensor_with_its_own_lag_leaves_no_parameter_confidently_wrong",
    ),
    Assumption(
        "parts-agree",
        "one motor over the whole record: the parameters are the same in every part",
        "with non-white residuals, the chosen model refitted on two disjoint parts (the "
        "segments alternately, or the halves of a single one); a parameter both parts "
        "identify must agree within 3 combined standard errors",
        Treatment.CHANGE,
        "the parameter is flagged not identifiable, both values in the reason, with what "
        "to record",
        Stage.FIT,
        ("parts-agree",),
        _A + "test_parts_that_disagree_flag_the_parameter",
    ),
    Assumption(
        "electrical-resolution",
        "the sample rate resolves the electrical time constant, or L shows reliably in "
        "the first sample after each voltage step",
        "with non-white current residuals, L/R against the sample period",
        Treatment.CHANGE,
        "L/R below one sample: L flagged, with the rate that resolves it (only a rate a "
        "drive's current sense offers, <= 100 kHz) or an LCR meter",
        Stage.FIT,
        ("electrical-resolution",),
        _T + "test_a_filtered_current_on_a_fast_armature_flags_l",
    ),
    Assumption(
        "kt-equals-ke",
        "Kt = Ke in SI units (closes the scale of Kt, J, B)",
        "none on voltage, current and speed alone (the scale is invisible); runs with a "
        "known added inertia measure Kt",
        Treatment.CHANGE,
        "Kt is reported as assumed (`identifiable: false`, no interval), never as "
        "measured; --fix Kt=..., --fix J=... or --added-inertia replace it",
        Stage.FIT,
        ("kt-equals-ke",),
        _A + "test_kt_is_reported_as_assumed_not_identified",
    ),
    Assumption(
        "gate-and-fit",
        "the gate's expected uncertainty (before the fit) and the fit's verdict describe "
        "one parameter",
        "a parameter the gate expects not identifiable (> 50 %) that the fit's simpler "
        "model reports identified (B with one steady speed: viscous and constant friction "
        "are one torque)",
        Treatment.CHANGE,
        "one message: the parameter is flagged with the gate's figure and why the fit's "
        "interval holds only under its model; R, Ke, J: the fit's own bound decides",
        Stage.FIT,
        ("identifiability",),
        _T + "test_a_step_from_rest_at_500_hz_gives_one_message_for_b",
    ),
    Assumption(
        "physical-range",
        "the fitted values are a motor's",
        "each value against the physical range export-model and --fix accept",
        Treatment.CHANGE,
        "a value outside is flagged; the motor file carries the nearest end of the range, "
        "said in its description, so export-model accepts what identify writes",
        Stage.FIT,
        ("physical-range",),
        _A + "test_a_value_outside_the_physical_range_is_flagged_and_the_yaml_exports",
    ),
    Assumption(
        "staircase-levels",
        "a staircase segment holds one steady level (a table row group or one time series "
        "per level)",
        "the command's holds inside a labelled staircase segment",
        Treatment.CHANGE,
        "a staircase segment that holds several levels is cut into them",
        Stage.FIT,
        ("staircase-levels",),
        _T + "test_an_8_level_staircase_in_one_segment_gives_its_levels",
    ),
    Assumption(
        "holdout-informative",
        "the held-out segments of diagnose's split carry information",
        "the no-excitation rule on the held-out side",
        Treatment.REFUSE,
        "exit 2: which held-out segments hold nothing and that --holdout should name a "
        "step, sweep or coast-down",
        Stage.DIAGNOSIS,
        ("holdout-informative",),
        _A + "test_a_held_out_side_without_information_is_refused",
    ),
)


def markdown_table() -> str:
    """:data:`REGISTER` as the table of ``docs/assumptions.md`` (a test keeps them equal)."""
    rows = [
        "| id | assumption | check on the data | when it fails | test (a record violating it) |",
        "| --- | --- | --- | --- | --- |",
    ]
    for a in REGISTER:
        treat = "**refused** (exit 2): " if a.treatment is Treatment.REFUSE else "changed: "
        rows.append(
            f"| `{a.id}` | {a.statement} | {a.check} | {treat}{a.on_failure} | `{a.test}` |"
        )
    return "\n".join(rows)


def by_id(ident: str) -> Assumption:
    for a in REGISTER:
        if a.id == ident:
            return a
    raise KeyError(ident)


# ---------------------------------------------------------------------------
# data stage
# ---------------------------------------------------------------------------
def continues(seg: Segment) -> bool:
    """``seg`` was read as the continuation of the segment before it (it carries
    history: commands or heat of that record)."""
    hv = seg.history_voltage
    return (hv is not None and hv.size > 0) or seg.history_heat_a2s is not None


def segment_reading(segments: Iterable[Segment]) -> list[dict[str, Any]]:
    """How the segments were read: label, first and last time, continues the one before.

    The same function for every command's JSON (``assumptions_checked.segments``), so
    two commands' reading of one file can be compared."""
    return [
        {
            "label": s.label,
            "t0": float(s.t[0]),
            "t1": float(s.t[-1]),
            "samples": s.n,
            "continues": continues(s),
        }
        for s in segments
    ]


def separate_runs(run: Run) -> list[tuple[str, str]]:
    """Segments on the same clock as the one before (one period later) that are not
    its continuation: (label, the jump that says why)."""
    from pmdc_ident.core.continuity import boundary_jump, step_limits
    from pmdc_ident.core.data import same_clock

    segs = run.segments
    limits = step_limits(segs)
    out = []
    for prev, seg in zip(segs[:-1], segs[1:], strict=True):
        if not same_clock(prev, seg) or continues(seg):
            continue
        jump = boundary_jump(prev, seg, limits)
        out.append((seg.label, jump.describe() if jump is not None else "its samples jump"))
    return out


def data_findings(where: str, run: Run) -> list[Finding]:
    """The register's own findings on one input (the gate adds them to its report)."""
    from pmdc_ident.core.quality.findings import Finding, Severity
    from pmdc_ident.core.segmentation import is_unlabeled

    found = separate_runs(run)
    if not found:
        return []
    labels = ", ".join(label for label, _ in found[:6]) + (", ..." if len(found) > 6 else "")
    first = found[0][1]
    if is_unlabeled(run):
        text = (
            f"a new run starts with the rotor at rest one sample period after the one "
            f"before ({first}): {labels} read as separate runs, each from its own first "
            "sample (a position that restarts with a run is not a wrap)"
        )
    else:
        text = (
            f"{labels} start{'s' if len(found) == 1 else ''} one sample period after the "
            f"segment before, but not from its last state ({first}): read as separate runs, "
            "each from its own first sample (a clock that runs on does not make one record)"
        )
    return [Finding("continuity", Severity.WARNING, where, text, value=float(len(found)))]


# ---------------------------------------------------------------------------
# diagnosis stage
# ---------------------------------------------------------------------------
def check_holdout(held_out: Sequence[Segment], rule: str) -> None:
    """Refuse (exit 2) a split whose held-out side carries no information: its gap
    could not show anything, and ``no_gap`` would mean nothing."""
    from pmdc_ident.core.data import excitation_problem
    from pmdc_ident.core.errors import DataError, option_name

    problem = excitation_problem(held_out) if held_out else ("nothing is held out", "")
    if problem is None:
        return
    what, _fix = problem
    labels = ", ".join(s.label for s in held_out) or "-"
    hint = f"{option_name('holdout')} should name" if rule == "user" else "record"
    msg = (
        f"the held-out segments ({labels}) carry no information ({what}): the held-out gap "
        f"could not show a missing effect; {hint} a step, a sweep or a coast-down"
    )
    raise DataError(msg)


# ---------------------------------------------------------------------------
# the JSON
# ---------------------------------------------------------------------------
def register_json(
    findings: Iterable[Finding],
    segments: Iterable[Segment],
    flags: Mapping[str, str] | None = None,
) -> dict[str, Any]:
    """``assumptions_checked`` of a command's JSON: the segments as read, and per
    assumption of the data and fit stages ``ok`` or what was done (``changed``,
    ``refused``) with the line that said it."""
    from pmdc_ident.core.quality.findings import Severity

    found = list(findings)
    flags = dict(flags or {})
    out: dict[str, Any] = {}
    for a in REGISTER:
        hit = [
            f
            for f in found
            if f.code in a.codes and f.severity is not Severity.INFO and _concerns(a, f)
        ]
        said = [f.line() for f in hit] + [v for k, v in flags.items() if k in a.codes]
        if not said:
            out[a.id] = {"status": "ok"}
            continue
        refused = any(f.severity is Severity.ERROR for f in hit)
        out[a.id] = {"status": "refused" if refused else "changed", "said": said}
    return {"segments": segment_reading(segments), "register": out}


def _concerns(a: Assumption, f: Finding) -> bool:
    if a.id == "position-restart":
        return f.code == "position-wrap" or "restarts with a run" in f.message
    if a.id == "continuity":
        return "restarts with a run" not in f.message
    return True
