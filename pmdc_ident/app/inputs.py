"""DATA as the service reads them: columns and units applied (``dataio.units``), isolated
outliers found, then the data-quality gate (``core.quality``) before any fit, the
automatic segments and a long record's representative subset.

ROS-free and free of the command line: every function takes the parsed
:class:`~pmdc_ident.app.options.InputOptions`, and a hint that names an option says it
in the caller's words (:meth:`InputOptions.name`). Lines for the user go to a ``show``
callback, progress to a ``progress`` callback (the caller decides where they print).
Light at import time: numpy and the core load inside the functions.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pmdc_ident.app.options import CLI_NAMES, InputOptions

if TYPE_CHECKING:
    from pmdc_ident.core.data import Run
    from pmdc_ident.core.quality import QualityReport
    from pmdc_ident.dataio.units import LoadedInput

__all__ = [
    "LONG_SAMPLES",
    "Show",
    "check_ignore",
    "gate",
    "input_json",
    "load_inputs",
    "load_side",
    "loaded_run",
    "prepare_inputs",
    "quality",
    "quiet",
    "recording_of",
    "segment_inputs",
    "show_incomplete",
    "show_quality",
    "stop_on_errors",
]

Show = Callable[[str], None]


def quiet(_: str) -> None:
    """A ``show``/``progress`` callback that says nothing."""


def load_inputs(options: InputOptions, progress: Show | None = None) -> list[LoadedInput]:
    """Every DATA argument in SI units (command-line keys over each file's sidecar).

    A recording that is not whole (an interrupted session, a truncated bag, segments
    cut short, a topic at another rate) carries what was left out in its notes, so
    the gate, the progress lines and the JSON (:func:`input_json`) say so."""

    from pmdc_ident.dataio.units import UNIT_OPTIONS, load_input, spec_from_options

    units = {k: getattr(options, k) for k in UNIT_OPTIONS}
    spec = spec_from_options(column=options.column, **units)
    out = []
    for p in options.data:
        if progress is not None:
            try:
                size = f" ({Path(p).stat().st_size / 1e6:.3g} MB)" if Path(p).is_file() else ""
            except OSError:
                size = ""
            progress(f"reading {p}{size}")
        out.append(_screen(_with_recording_notes(load_input(p, spec)), options.drop_outliers))
    return out


def _with_recording_notes(x: LoadedInput) -> LoadedInput:
    """``x`` with what its recording left out in its notes (a bag; a CSV has none)."""
    from dataclasses import replace

    state = recording_of(x.path)
    if state is None:
        return x
    lines = state.lines(truncation=False)
    return replace(x, notes=(*x.notes, *(s.removeprefix(f"{state.source}: ") for s in lines)))


def loaded_run(
    options: InputOptions, run: Run, path: str, origin: str = "samples in SI units"
) -> list[LoadedInput]:
    """A run already in SI units (a session's samples, assembled as its bag would be)
    as the one input of ``options``, named ``path``: screened for outliers as
    :func:`load_inputs` screens a file, with what its assembly left out in its notes
    (:func:`pmdc_ident.dataio.bagio.assemble_run` of ``path`` in this process, as for a
    bag). ``origin``: where the units came from (``inputs.<path>.units.origin``)."""
    from pmdc_ident.dataio.units import InputSpec, LoadedInput

    x = _with_recording_notes(LoadedInput(path, run, InputSpec(origin=origin), ()))
    return [_screen(x, options.drop_outliers)]


def _screen(x: LoadedInput, drop: bool) -> LoadedInput:
    """``x`` with its isolated outliers found (and left out when ``drop``)."""
    from dataclasses import replace

    from pmdc_ident.dataio.outliers import drop_outliers, find_outliers

    found = find_outliers(x.run)
    _OUTLIERS[x.path] = (found, drop)
    if found and drop:
        x = replace(x, run=drop_outliers(x.run, found))
    return x


# DATA path -> (isolated outliers found, left out?) of the inputs loaded last
_OUTLIERS: dict[str, tuple[list[Any], bool]] = {}


def _csv_lines(path: str, rows: list[int]) -> dict[int, int]:
    """The file line of each data row (0-based, comments and blank lines skipped)."""
    wanted = set(rows)
    out: dict[int, int] = {}
    row = -1  # the header is row -1
    try:
        with open(path, encoding="utf-8-sig") as fh:
            for line_no, line in enumerate(fh, start=1):
                if not line.strip() or line.lstrip().startswith("#"):
                    continue
                if row in wanted:
                    out[row] = line_no
                    if len(out) == len(wanted):
                        break
                row += 1
    except (OSError, UnicodeDecodeError):
        return {}
    return out


def outlier_findings(inputs: list[LoadedInput], names: Mapping[str, str] = CLI_NAMES) -> list[Any]:
    """The ``outlier`` findings of the loaded inputs: an error per signal (the lines and
    values), or a warning saying they were left out (``--drop-outliers``)."""
    from pmdc_ident.core.quality.findings import Finding, Severity

    drop_name = names.get("drop_outliers", "drop_outliers")
    findings = []
    for x in inputs:
        found, dropped = _OUTLIERS.get(x.path, ([], False))
        if not found:
            continue
        is_csv = not (x.path.endswith(".mcap") or Path(x.path).is_dir())
        lines = _csv_lines(x.path, [o.row for o in found]) if is_csv else {}
        by_signal: dict[str, list[Any]] = {}
        for o in found:
            by_signal.setdefault(o.signal, []).append(o)
        for signal, items in by_signal.items():
            shown = "; ".join(o.describe(lines.get(o.row)) for o in items[:4])
            more = f"; and {len(items) - 4} more" if len(items) > 4 else ""
            if dropped:
                findings.append(
                    Finding(
                        "outlier",
                        Severity.WARNING,
                        x.path,
                        f"{len(items)} isolated {signal} outlier(s) left out ({drop_name}), "
                        f"the fit steps over them as gaps: {shown}{more}",
                        value=float(len(items)),
                    )
                )
                continue
            findings.append(
                Finding(
                    "outlier",
                    Severity.ERROR,
                    x.path,
                    f"{len(items)} isolated {signal} outlier(s), far outside the signal's own "
                    f"range for one or two samples (a glitch or a mistyped cell the fit would "
                    f"read as physics): {shown}{more}",
                    f"correct those cells, or {drop_name} to fit around them",
                    value=float(len(items)),
                )
            )
    return findings


def recording_of(path: str) -> Any:
    """The bag reader's :class:`~pmdc_ident.dataio.bagio.RecordingState` of ``path``, or
    None (a CSV; the bag module is not even imported then)."""
    bagio = sys.modules.get("pmdc_ident.dataio.bagio")
    return None if bagio is None else bagio.recording_state(path)


def show_incomplete(inputs: list[LoadedInput], show: Show) -> None:
    """One line per way a recording is not whole (and per topic joined at another
    rate), in the command's report."""
    for x in inputs:
        state = recording_of(x.path)
        if state is None:
            continue
        joined = [f"{state.source}: {j}" for j in state.join]
        for line in state.lines():
            whole = state.complete or line in joined
            show(f"recording{'' if whole else ' incomplete'}: {line}")


def segment_inputs(
    options: InputOptions, inputs: list[LoadedInput], show: Show = print
) -> list[LoadedInput]:
    """Unlabeled logs cut into their experiments (shown; usable as held-out labels)."""
    if options.no_auto_segments:
        return inputs
    from dataclasses import replace

    from pmdc_ident.core.segmentation import segment_run

    out = []
    for x in inputs:
        try:
            run, lines = segment_run(x.run)
        except (ArithmeticError, ValueError, IndexError) as exc:  # data nobody foresaw
            show(f"segments: {x.path} kept as one segment ({type(exc).__name__}: {exc})")
            run, lines = x.run, []
        if lines:
            keep = options.name("no_auto_segments")
            show(f"segments found in {x.path} (no segment column; {keep} keeps one):")
            for line in lines[:MAX_SEGMENT_LINES]:
                show(f"  {line}")
            if len(lines) > MAX_SEGMENT_LINES:
                kinds = _kind_counts([s.label for s in run.segments])
                show(f"  ... and {len(lines) - MAX_SEGMENT_LINES} more; in all {kinds}")
            x = replace(x, run=run, notes=(*x.notes, f"segments found: {len(lines)}"))
        out.append(x)
    return out


MAX_SEGMENT_LINES = 40  # segments listed one per line; the rest counted by kind


def _kind(label: str) -> str:
    head, _, tail = label.rpartition("_")
    return head if head and tail.isdigit() else label


def _kind_counts(labels: list[str]) -> str:
    counts: dict[str, int] = {}
    for label in labels:
        counts[_kind(label)] = counts.get(_kind(label), 0) + 1
    return ", ".join(f"{n} {k}" for k, n in counts.items())


# -- long records ------------------------------------------------------------------
# Above this many samples (about 4 minutes at 1 kHz) the physics checks of the gate and
# the fit use a representative subset of the record's segments (--all-samples: all).
LONG_SAMPLES = 250_000
# codes of the checks that run on every sample of a long record (cheap, linear)
WHOLE_RECORD_CODES = frozenset(
    {
        "sample-period",
        "jitter",
        "gaps",
        "voltage-unit",
        "current-unit",
        "speed-unit",
        "clipping",
        "current-missing",
        "voltage-missing",
    }
)


def is_long(options: InputOptions, inputs: list[LoadedInput]) -> bool:
    """A record too long to fit whole by default (and not ``all_samples``)."""
    if options.all_samples:
        return False
    return any(sum(s.n for s in x.run.segments) > LONG_SAMPLES for x in inputs)


def _spread(n: int) -> list[int]:
    """0..n-1 in an order that spreads every prefix over the range (first, last, middle,
    quarters, ...)."""
    if n <= 0:
        return []
    order: list[int] = [0] + ([n - 1] if n > 1 else [])
    seen = set(order)
    step = n
    while len(order) < n:
        step = max(1, step // 2)
        for k in range(step // 2 if step > 1 else 0, n, step):
            if k not in seen:
                seen.add(k)
                order.append(k)
    return order


def representative(
    x: LoadedInput,
    budget: int = LONG_SAMPLES,
    keep: tuple[str, ...] = (),
    names: Mapping[str, str] = CLI_NAMES,
) -> tuple[LoadedInput, str]:
    """A subset of ``x``'s segments of at most ``budget`` samples: every kind of segment
    (step_up, sweep, coast, ...), each kind's segments taken spread over the record
    (first, last, middle, ...), in record order; ``keep`` labels always. A record that is
    one long segment gives evenly spaced windows (each fitted from its own initial
    state). Returns the input and one line saying what was taken (``''``: all of it)."""
    from dataclasses import replace

    from pmdc_ident.core.data import Run

    segs = list(x.run.segments)
    total = sum(s.n for s in segs)
    if total <= budget:
        return x, ""
    if len(segs) == 1:
        seg = segs[0]
        windows = 8
        width = budget // windows
        starts = [round(k * (seg.n - width) / (windows - 1)) for k in range(windows)]
        chosen = [
            seg.slice(a, a + width, label=f"{seg.label}.{k + 1}") for k, a in enumerate(starts)
        ]
    else:
        by_kind: dict[str, list[int]] = {}
        for k, s in enumerate(segs):
            by_kind.setdefault(_kind(s.label), []).append(k)
        queues = {kind: [idx[j] for j in _spread(len(idx))] for kind, idx in by_kind.items()}
        picked = {k for k, s in enumerate(segs) if s.label in keep}
        used = sum(segs[k].n for k in picked)
        progress = True
        while progress:
            progress = False
            for q in queues.values():
                while q and q[0] in picked:
                    q.pop(0)
                if not q:
                    continue
                k = q[0]
                first_of_kind = not any(j in picked for j in by_kind[_kind(segs[k].label)])
                if used + segs[k].n <= budget or first_of_kind:
                    picked.add(q.pop(0))
                    used += segs[k].n
                    progress = True
        chosen = [segs[k] for k in sorted(picked)]
    n = sum(s.n for s in chosen)
    line = (
        f"long record: {total} samples in {len(segs)} segment(s); the physics checks and the "
        f"fit use a representative {n} samples ({len(chosen)} segments: "
        f"{_kind_counts([s.label for s in chosen])}, spread over the record); timing, units, "
        "clipping, outliers and completeness are checked on every sample "
        f"({names.get('all_samples', 'all_samples')} uses all of them)"
    )
    run = Run(tuple(chosen), source=x.run.source)
    return replace(x, run=run, notes=(*x.notes, line)), line


def _whole_record_findings(inputs: list[LoadedInput]) -> list[Any]:
    """The cheap checks of :data:`WHOLE_RECORD_CODES` on every sample of ``inputs``."""
    from pmdc_ident.core.quality.findings import Finding, Severity
    from pmdc_ident.core.quality.scales import check_magnitudes
    from pmdc_ident.core.quality.signals import check_clipping, check_columns
    from pmdc_ident.core.quality.timing import check_timing

    out: list[Any] = []
    for x in inputs:
        segs = x.run.segments
        declared = x.spec.declared()
        for check, extra in (
            (check_timing, ()),
            (check_columns, ()),
            (check_magnitudes, (declared,)),
            (check_clipping, ()),
        ):
            try:
                found = check(x.path, segs, *extra)  # type: ignore[operator]
                out += [f for f in found if f.code in WHOLE_RECORD_CODES]
            except (ArithmeticError, ValueError, IndexError) as exc:
                out.append(
                    Finding(
                        "check-failed",
                        Severity.WARNING,
                        x.path,
                        f"a check could not run on these data ({type(exc).__name__}); "
                        "the others did",
                    )
                )
    return out


def quality(
    options: InputOptions,
    inputs: list[LoadedInput],
    fixed: Mapping[str, float] | None = None,
    whole: list[LoadedInput] | None = None,
) -> QualityReport:
    """The gate's findings on ``inputs`` (the ``ignore`` codes' errors turned into warnings);
    ``fixed`` parameters are left out of the expected uncertainties. ``whole``: the full
    records of which ``inputs`` are representative subsets (a long record): the checks
    of :data:`WHOLE_RECORD_CODES` and the outliers then come from every sample."""
    from pmdc_ident.core.quality import GateInput, QualityReport, check_inputs

    ignore = list(options.ignore)
    report = check_inputs(
        [GateInput(x.path, x.run, x.spec.declared(), x.notes) for x in inputs],
        fixed=fixed,
        ignore=ignore,
    )
    findings = list(report.findings)
    if whole is not None:
        findings = [f for f in findings if f.code not in WHOLE_RECORD_CODES]
        findings += _whole_record_findings(whole)
    extra = outlier_findings(whole if whole is not None else inputs, options.names)
    if not extra and whole is None:
        return report
    merged = QualityReport.of([*extra, *findings], report.expected_rsd)
    return merged.downgraded(ignore)


def show_quality(report: QualityReport, *, show: Show = print, info: bool = False) -> None:
    """Print the findings (errors and warnings; ``info`` adds the measurements)."""
    lines = report.lines(info=info)
    if lines:
        show("data quality:")
        for line in lines:
            show(f"  {line}")


def check_ignore(codes: Iterable[str], names: Mapping[str, str] = CLI_NAMES) -> None:
    """Each ``ignore`` code names a finding code (checked before any work)."""
    from pmdc_ident.core.errors import ParameterError
    from pmdc_ident.core.quality.findings import CODES

    bad = [c for c in codes or () if c not in CODES]
    if bad:
        flag = names.get("ignore", "ignore")
        msg = f"{flag} {bad[0]}: not a finding code (codes: {', '.join(CODES)})"
        raise ParameterError(msg)


def stop_on_errors(report: QualityReport, names: Mapping[str, str] = CLI_NAMES) -> None:
    """Refuse to go on (:class:`DataError`, exit 2) when an error remains; the line
    carries the first error itself (the others are listed above it)."""
    from pmdc_ident.core.errors import DataError

    if report.errors:
        first = report.errors[0]
        more = len(report.errors) - 1
        fix = f"; fix: {first.fix}" if first.fix else ""
        also = f" (and {more} more above)" if more else ""
        msg = (
            f"data quality: {first.code}: {first.where}: {first.message}{fix}{also}; "
            f"nothing was fitted ({names.get('ignore', 'ignore')} CODE goes on anyway)"
        )
        raise DataError(msg)


def gate(
    options: InputOptions,
    inputs: list[LoadedInput],
    *,
    show: Show = print,
    info: bool = False,
    whole: list[LoadedInput] | None = None,
) -> QualityReport:
    """:func:`quality`, :func:`show_quality`, :func:`stop_on_errors`: the gate before a fit."""
    check_ignore(options.ignore, options.names)
    report = quality(options, inputs, options.fixed, whole)
    show_quality(report, show=show, info=info)
    stop_on_errors(report, options.names)
    return report


def prepare_inputs(
    options: InputOptions,
    show: Show,
    progress: Show = quiet,
    loaded: list[LoadedInput] | None = None,
) -> tuple[list[LoadedInput], QualityReport]:
    """What ``identify`` and ``diagnose`` do first: read the DATA (their notes as
    progress; ``loaded``: inputs already read, e.g. :func:`loaded_run`), run the
    :func:`gate`, cut the automatic segments, take a long record's representative
    subset. Returns the inputs and the gate's report."""
    inputs = load_inputs(options, progress) if loaded is None else loaded
    for x in inputs:
        for note in x.notes:
            progress(f"{x.path}: {note}")
    show_incomplete(inputs, show)
    if is_long(options, inputs):
        chosen = long_subset(options, segment_inputs(options, inputs, show=show), show, progress)
        report = gate(options, chosen, show=show, whole=inputs)
        return chosen, report
    report = gate(options, inputs, show=show)
    return segment_inputs(options, inputs, show=show), report


def long_subset(
    options: InputOptions, inputs: list[LoadedInput], show: Show, progress: Show
) -> list[LoadedInput]:
    """Each long input's representative subset (:func:`representative`), said once."""
    keep = tuple(getattr(options, "holdout", ()) or ())  # diagnose's held-out labels
    out = []
    for x in inputs:
        x, line = representative(x, budget=LONG_SAMPLES, keep=keep, names=options.names)
        if line:
            show(f"{x.path}: {line}")
            progress(f"{x.path}: {line}")
        out.append(x)
    return out


# load-side value = motor-side value * gear_ratio ** power (N motor turns per load turn)
_REFLECT = {"Ke": 1, "Kt": 1, "J": 2, "B": 2, "coulomb_friction.torque_nm": 1}


def load_side(values: dict[str, float], inputs: list[LoadedInput]) -> dict[str, Any]:
    """The parameters seen from the load side of the gear (``--gear-ratio N``), else {}."""
    gears = {x.spec.gear_ratio for x in inputs}
    if gears == {None}:
        return {}
    if len(gears) != 1:
        return {"note": "inputs have different gear ratios: no load-side values"}
    (n,) = gears
    assert n is not None
    out: dict[str, Any] = {
        name: values[name] * n**power for name, power in _REFLECT.items() if name in values
    }
    out["gear_ratio"] = n
    out["note"] = (
        f"seen from the load side of a {n:g}:1 gear (Ke, Kt, torques x {n:g}; J, B x {n:g}^2; "
        "gear losses not included)"
    )
    return out


def input_json(inputs: list[LoadedInput], report: QualityReport) -> dict[str, Any]:
    """The ``quality``, ``inputs`` (units applied per file) and ``recording`` keys of a
    command's JSON. ``recording`` says, per bag, whether it is whole: an interrupted
    session, a truncated file, the segments left out (``complete`` false); and
    ``recording_complete`` whether every input is."""
    states = {x.path: recording_of(x.path) for x in inputs}
    recording = {p: s.to_json() for p, s in states.items() if s is not None}
    return {
        "quality": report.to_json(),
        "inputs": {x.path: {"units": x.spec.to_json(), "notes": list(x.notes)} for x in inputs},
        "recording": recording,
        "recording_complete": all(r["complete"] for r in recording.values()),
    }
