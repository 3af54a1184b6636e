"""Data in, documents out: ``identify``, ``diagnose`` and ``check`` below the command line
and the identification node.

Each function takes parsed options (:mod:`pmdc_ident.app.options`), reads the DATA (or
takes inputs already read: the node's session), runs the data-quality gate, the
automatic segments and the long-record subset (:mod:`pmdc_ident.app.inputs`), then the
job, and returns its documents: the JSON dict (and its text), the motor YAML, and the
lines for the user, in the order they were shown. ``show`` receives each line as it
comes (the command line prints it at once: a fit takes a while); ``progress`` the
progress lines. Nothing is written here: the caller writes the documents through its
safe writers. Refusals are the project's errors (:mod:`pmdc_ident.core.errors`) in the
caller's words for its options.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pmdc_ident.app.inputs import (
    Show,
    check_ignore,
    input_json,
    is_long,
    load_inputs,
    load_side,
    long_subset,
    prepare_inputs,
    quality,
    quiet,
    segment_inputs,
    show_incomplete,
    show_quality,
    stop_on_errors,
)
from pmdc_ident.app.options import CheckOptions, DiagnoseOptions, IdentifyOptions
from pmdc_ident.core.errors import ParameterError

if TYPE_CHECKING:
    from pmdc_ident.core.data import Run, Segment
    from pmdc_ident.core.identification.results import IdentificationResult
    from pmdc_ident.core.quality import QualityReport
    from pmdc_ident.dataio.units import LoadedInput

__all__ = [
    "CheckDocuments",
    "DiagnoseDocuments",
    "IdentifyDocuments",
    "check_diagnose_options",
    "check_identify_options",
    "check_inputs",
    "diagnose_inputs",
    "identify_inputs",
]


def _collect(lines: list[str], show: Show | None) -> Show:
    """A ``show`` that keeps each line in ``lines`` and passes it on."""

    def out(line: str) -> None:
        lines.append(line)
        if show is not None:
            show(line)

    return out


# -- identify ----------------------------------------------------------------------
@dataclass
class IdentifyDocuments:
    """What ``identify`` produced: the result, its JSON dict and the lines shown."""

    result: IdentificationResult
    segments: list[Segment]  # what was fitted (the report's plots)
    inputs: list[LoadedInput]
    report: QualityReport
    body: dict[str, Any]
    lines: list[str]
    motor_name: str = "identified"

    @property
    def json_text(self) -> str:
        """The JSON document (``pmdc-ident identify --json``, the node's result)."""
        return json.dumps(self.body, indent=2, allow_nan=False) + "\n"

    @property
    def yaml_text(self) -> str:
        """The motor file (``pmdc-ident identify --yaml -``, the node's parameters.yaml)."""
        return self.result.motor_yaml(self.motor_name)

    @property
    def values(self) -> dict[str, float]:
        return {k: p.value for k, p in self.result.parameters.items()}


def check_identify_options(options: IdentifyOptions) -> None:
    """Refuse options that cannot work together, before any data is read."""
    check_ignore(options.ignore, options.names)
    if options.closure == "none" and not (
        {"Kt", "J"} & set(options.fixed) or options.added_inertia
    ):
        fix, added = options.name("fix"), options.name("added_inertia")
        msg = (
            f"{options.name('closure')} none leaves the scale of (Kt, J, B) unidentifiable "
            f"from voltage, current and speed: give {fix} Kt=..., {fix} J=... or "
            f"{added} DATA=KG_M2"
        )
        raise ParameterError(msg)


def identify_inputs(
    options: IdentifyOptions,
    *,
    show: Show | None = None,
    progress: Show = quiet,
    loaded: list[LoadedInput] | None = None,
    extra: Mapping[str, Any] | None = None,
) -> IdentifyDocuments:
    """Gate, segment and identify the DATA of ``options`` (or the ``loaded`` inputs);
    ``extra`` entries are added at the end of the JSON dict (the node's session)."""
    from pmdc_ident.core.estimators.output_error import CLOSURE_KT_KE
    from pmdc_ident.core.identification.identify import identify, merge_runs

    check_identify_options(options)
    lines: list[str] = []
    out = _collect(lines, show)
    inputs, report = prepare_inputs(options, out, progress, loaded)
    runs = [x.run for x in inputs]
    segments = merge_runs(runs)
    added = _added_inertia(options, runs, segments)
    result = identify(
        segments,
        sources=tuple(r.source for r in runs),
        fixed=options.fixed,
        closure=CLOSURE_KT_KE if options.closure == "Kt=Ke" else None,
        model=options.model,
        holdout=options.holdout_check,
        bootstrap=options.bootstrap,
        progress=progress,
        added_inertia=added,
        findings=report.findings,
        expected_rsd=report.expected_rsd,
    )
    out(result.text_report())
    body = result.to_json_dict()
    body.update(input_json(inputs, report))
    gear = load_side({k: p.value for k, p in result.parameters.items()}, inputs)
    if gear:
        body["load_side"] = gear
        out("load side: " + gear["note"])
        values = ", ".join(f"{k} = {v:.6g}" for k, v in gear.items() if k != "note")
        out(f"  {values}")
    body.update(extra or {})
    return IdentifyDocuments(result, segments, inputs, report, body, lines, options.motor_name)


def _added_inertia(options: IdentifyOptions, runs: list[Run], segments: list[Segment]):
    """``DATA=KG_M2`` items to segment labels (segments keep the order of the files)."""
    flag = options.name("added_inertia")
    per_file: dict[str, float] = {}
    for item in options.added_inertia:
        path, sep, value = item.rpartition("=")
        try:
            per_file[path] = float(value)
        except ValueError:
            per_file[path] = math.nan
        if not sep or not path or not math.isfinite(per_file[path]):
            msg = f"{flag} expects DATA=KG_M2 (e.g. run2.csv=0.002), got {item!r}"
            raise ParameterError(msg)
    out: dict[str, float] = {}
    start = 0
    spans = []
    for path, r in zip(options.data, runs, strict=True):
        spans.append((path, segments[start : start + len(r)]))
        start += len(r)
    for path, value in per_file.items():
        if value < 0:
            msg = f"{flag} {path}: must be >= 0 kg*m^2, got {value:g}"
            raise ParameterError(msg)
        match = [
            segs for p, segs in spans if p == path or Path(p).resolve() == Path(path).resolve()
        ]
        if not match:
            msg = f"{flag} {path}: not one of the {options.name('data')} arguments"
            raise ParameterError(msg)
        for s in match[0]:
            out[s.label] = value
    return out


# -- diagnose ----------------------------------------------------------------------
@dataclass
class DiagnoseDocuments:
    """What ``diagnose`` produced: the result, the lines shown and (on demand) the JSON."""

    result: Any  # core.diagnosis.DiagnosisResult
    runs: list[Run]
    inputs: list[LoadedInput]
    report: QualityReport
    lines: list[str]

    @cached_property
    def body(self) -> dict[str, Any]:
        """The JSON dict (``pmdc-ident diagnose --json``)."""
        from pmdc_ident.core.assumptions import register_json
        from pmdc_ident.core.data import unique_labels

        body = self.result.to_json()
        body.update(input_json(self.inputs, self.report))
        segments = unique_labels(s for r in self.runs for s in r.segments)
        body["assumptions_checked"] = register_json(self.report.findings, segments)
        return body

    @property
    def json_text(self) -> str:
        return json.dumps(self.body, indent=2) + "\n"


def check_diagnose_options(options: DiagnoseOptions) -> None:
    """Refuse an empty or unknown effect list, or a combination size below 1."""
    from pmdc_ident.core.effects import EFFECT_NAMES

    check_ignore(options.ignore, options.names)
    flag = options.name("effects")
    if not options.effects:
        msg = f"{flag} lists no effect (give one or more of: {', '.join(EFFECT_NAMES)})"
        raise ParameterError(msg)
    unknown = [e for e in options.effects if e not in EFFECT_NAMES]
    if unknown:
        msg = f"{flag}: unknown effect {unknown[0]!r} (known: {', '.join(EFFECT_NAMES)})"
        raise ParameterError(msg)
    if options.max_effects < 1:
        msg = (
            f"{options.name('max_effects')} must be >= 1 (effects combined at most), "
            f"got {options.max_effects}"
        )
        raise ParameterError(msg)


def diagnose_inputs(
    options: DiagnoseOptions,
    *,
    show: Show | None = None,
    progress: Show = quiet,
    loaded: list[LoadedInput] | None = None,
) -> DiagnoseDocuments:
    """Gate, segment and diagnose the DATA of ``options`` (or the ``loaded`` inputs)."""
    from pmdc_ident.core.diagnosis import DiagnosisConfig, diagnose

    check_diagnose_options(options)
    config = DiagnosisConfig(
        holdout=tuple(options.holdout),
        effects=tuple(options.effects),
        fixed=options.fixed,
        max_effects=options.max_effects,
    )
    lines: list[str] = []
    out = _collect(lines, show)
    inputs, report = prepare_inputs(options, out, progress, loaded)
    runs = [x.run for x in inputs]
    result = diagnose(runs, config=config, progress=progress)
    out("\n".join(result.summary_lines()))
    out("split: " + "; ".join(result.split.description))
    return DiagnoseDocuments(result, runs, inputs, report, lines)


# -- check -------------------------------------------------------------------------
@dataclass
class CheckDocuments:
    """What ``check`` found: the gate's report, the lines shown, the JSON on demand."""

    report: QualityReport
    inputs: list[LoadedInput]  # read whole
    segmented: list[LoadedInput]  # as checked (segments found; a long record's subset)
    lines: list[str]
    names: Mapping[str, str] = field(default_factory=dict)

    @cached_property
    def body(self) -> dict[str, Any]:
        """The JSON dict (``pmdc-ident check --json``)."""
        from pmdc_ident.core.assumptions import register_json
        from pmdc_ident.core.data import unique_labels

        segments = unique_labels(s for x in self.segmented for s in x.run.segments)
        return {
            "sources": [x.path for x in self.inputs],
            **input_json(self.segmented, self.report),
            "assumptions_checked": register_json(self.report.findings, segments),
        }

    @property
    def json_text(self) -> str:
        return json.dumps(self.body, indent=2, allow_nan=False) + "\n"

    def stop_on_errors(self) -> str:
        """:class:`~pmdc_ident.core.errors.DataError` when an error would stop a fit;
        else the closing line (``ok: no errors, N warning(s)``)."""
        stop_on_errors(self.report, self.names)
        return f"ok: no errors, {len(self.report.warnings)} warning(s)"


def check_inputs(
    options: CheckOptions, *, show: Show | None = None, progress: Show = quiet
) -> CheckDocuments:
    """The data-quality gate alone, every finding shown with its measurement. Does not
    raise on the gate's errors: :meth:`CheckDocuments.stop_on_errors` does (after the
    caller wrote the JSON)."""
    check_ignore(options.ignore, options.names)
    lines: list[str] = []
    out = _collect(lines, show)
    inputs = load_inputs(options, progress)
    show_incomplete(inputs, out)
    if is_long(options, inputs):  # the physics checks on a representative subset
        progress("finding the segments of the long record")
        segmented = segment_inputs(options, inputs, show=out)
        chosen = long_subset(options, segmented, out, progress)
        progress("checking")
        report = quality(options, chosen, options.fixed, whole=inputs)
        show_quality(report, info=True, show=out)
    else:
        progress("checking")
        report = quality(options, inputs, options.fixed)
        show_quality(report, info=True, show=out)
        segmented = segment_inputs(options, inputs, show=out)
    return CheckDocuments(report, inputs, segmented, lines, options.names)
