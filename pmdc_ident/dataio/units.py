"""Units and column names of recordings made by other tools, converted to SI.

A layer over the raw columns :mod:`pmdc_ident.dataio.csvio` (or a bag) reads:
an :class:`InputSpec` says which header holds which signal and in which unit
(``--column speed=Speed_rpm --speed-unit rpm``, or the same keys in a sidecar
YAML ``RUN.csv.yaml`` next to the recording) and :func:`load_input` returns the
run in the SI units the core works in (s, V, A, rad, rad/s), with one note per
conversion made.

=================  ==============================================  =========================
key                values                                          SI value
=================  ==============================================  =========================
``time_unit``      ``s`` ``ms`` ``us`` ``ns``                      t * 1, 1e-3, 1e-6, 1e-9
``speed_unit``     ``rad/s`` ``rpm`` ``deg/s`` ``rev/s``           w * 1, pi/30, pi/180, 2 pi,
                   ``counts/s``                                    2 pi / counts_per_rev
``position_unit``  ``rad`` ``deg`` ``rev`` ``counts``              same factors
``current_unit``   ``A`` ``mA``                                    i * 1, 1e-3
``voltage_unit``   ``V`` ``mV`` ``duty`` (-1..1) ``duty%``         V * 1, 1e-3, supply_v,
                                                                   supply_v / 100
``supply_v``       V                                               for ``duty``/``duty%``
``counts_per_rev`` encoder counts per shaft turn                   for ``counts``
``gear_ratio``     motor turns per load turn (speed and position   w, theta * gear_ratio
                   measured on the load side)
``columns``        ``{NAME: HEADER}``; ``-HEADER`` negates         (wires the other way)
=================  ==============================================  =========================

Keys given on the command line override the sidecar's, one by one.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from pmdc_ident.core.data import Run, Segment
from pmdc_ident.core.errors import DataError, DataOptionError, SignalRangeError
from pmdc_ident.core.errors import option_name as opt

__all__ = [
    "CurrentUnit",
    "InputSpec",
    "LoadedInput",
    "PositionUnit",
    "SpeedUnit",
    "TimeUnit",
    "VoltageUnit",
    "convert_run",
    "load_input",
    "read_sidecar",
    "UNIT_OPTIONS",
    "sidecar_path",
    "spec_from_options",
]

_TWO_PI = 2.0 * math.pi


class TimeUnit(enum.Enum):
    S = "s"
    MS = "ms"
    US = "us"
    NS = "ns"


class SpeedUnit(enum.Enum):
    RAD_S = "rad/s"
    RPM = "rpm"
    DEG_S = "deg/s"
    REV_S = "rev/s"
    COUNTS_S = "counts/s"


class PositionUnit(enum.Enum):
    RAD = "rad"
    DEG = "deg"
    REV = "rev"
    COUNTS = "counts"


class CurrentUnit(enum.Enum):
    A = "A"
    MA = "mA"


class VoltageUnit(enum.Enum):
    V = "V"
    MV = "mV"
    DUTY = "duty"
    DUTY_PERCENT = "duty%"


_TIME_FACTOR = {TimeUnit.S: 1.0, TimeUnit.MS: 1e-3, TimeUnit.US: 1e-6, TimeUnit.NS: 1e-9}
_ANGLE_FACTOR = {"rad": 1.0, "rpm": math.pi / 30.0, "deg": math.pi / 180.0, "rev": _TWO_PI}
_ALIASES = {"µs": "us", "rad_s": "rad/s", "rads": "rad/s", "deg_s": "deg/s", "rps": "rev/s"}
_UNIT_KEYS: dict[str, type[enum.Enum]] = {
    "time_unit": TimeUnit,
    "speed_unit": SpeedUnit,
    "position_unit": PositionUnit,
    "current_unit": CurrentUnit,
    "voltage_unit": VoltageUnit,
}
_NUMBER_KEYS = ("supply_v", "counts_per_rev", "gear_ratio")
_SIGNALS = ("t", "voltage", "current", "position", "speed", "terminal_voltage", "segment")


def parse_unit(enum_type: type[enum.Enum], text: str, key: str) -> Any:
    """``text`` as a member of ``enum_type`` (case-insensitive, a few aliases)."""
    low = _ALIASES.get(str(text).strip().lower(), str(text).strip().lower())
    for member in enum_type:
        if member.value.lower() == low:
            return member
    choices = "|".join(m.value for m in enum_type)
    msg = f"{key.replace('_', '-')}: {text!r} is not one of {choices}"
    raise DataError(msg)


def _positive(key: str, value: Any) -> float:
    from pmdc_ident.dataio.csvio import parse_number

    try:
        v = parse_number(value.strip()) if isinstance(value, str) else float(value)
    except (TypeError, ValueError):
        v = math.nan
    if not (math.isfinite(v) and v > 0):
        msg = f"{key.replace('_', '-')} must be a positive number, got {value!r}"
        raise DataError(msg)
    return v


def _flag(key: str, value: Any) -> bool:
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "yes", "1", "on"):
        return True
    if text in ("false", "no", "0", "off"):
        return False
    msg = f"{key.replace('_', '-')} must be true or false, got {value!r}"
    raise DataError(msg)


@dataclass(frozen=True)
class InputSpec:
    """What the columns of a recording are and their units (``None`` = the SI default)."""

    columns: tuple[tuple[str, str], ...] = ()
    time_unit: TimeUnit | None = None
    speed_unit: SpeedUnit | None = None
    position_unit: PositionUnit | None = None
    current_unit: CurrentUnit | None = None
    voltage_unit: VoltageUnit | None = None
    supply_v: float | None = None
    counts_per_rev: float | None = None
    gear_ratio: float | None = None
    # speed is the counts since the last sample (its mean over the interval): read its
    # running sum as the encoder's position instead
    speed_averaged: bool | None = None
    origin: str = "command line"

    def __post_init__(self) -> None:
        for name, header in self.columns:
            if name not in _SIGNALS:
                msg = f"column {name!r} is not one of {', '.join(_SIGNALS)} (in {self.origin})"
                raise DataError(msg)
            if not header.lstrip("-").strip():
                msg = f"column {name!r}: empty header name (in {self.origin})"
                raise DataError(msg)

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], origin: str) -> InputSpec:
        """From the keys of a sidecar YAML (``-`` and ``_`` both accepted in key names)."""
        kwargs: dict[str, Any] = {"origin": origin}
        for raw_key, value in data.items():
            key = str(raw_key).strip().replace("-", "_")
            if key in _UNIT_KEYS:
                kwargs[key] = parse_unit(_UNIT_KEYS[key], value, key)
            elif key in _NUMBER_KEYS:
                kwargs[key] = _positive(key, value)
            elif key == "speed_averaged":
                kwargs[key] = _flag(key, value)
            elif key in ("columns", "column"):
                if not isinstance(value, Mapping):
                    msg = f"{origin}: 'columns' must map NAME: HEADER, got {value!r}"
                    raise DataError(msg)
                kwargs["columns"] = tuple((str(k), str(v)) for k, v in value.items())
            else:
                known = ", ".join([*_UNIT_KEYS, *_NUMBER_KEYS, "speed_averaged", "columns"])
                msg = f"{origin}: unknown key {raw_key!r} (known: {known})"
                raise DataError(msg)
        return cls(**kwargs)

    def merged_over(self, base: InputSpec | None) -> InputSpec:
        """This spec's keys where given, else ``base``'s (columns merged by name)."""
        if base is None:
            return self
        changes: dict[str, Any] = {}
        for f in fields(self):
            if f.name in ("columns", "origin"):
                continue
            if getattr(self, f.name) is None:
                changes[f.name] = getattr(base, f.name)
        cols = dict(base.columns)
        cols.update(dict(self.columns))
        changes["columns"] = tuple(cols.items())
        changes["origin"] = f"{self.origin} over {base.origin}" if self.given else base.origin
        return replace(self, **changes)

    @property
    def given(self) -> bool:
        """True when any key was set."""
        return bool(self.columns) or any(
            getattr(self, f.name) is not None
            for f in fields(self)
            if f.name not in ("columns", "origin")
        )

    def column_map(self) -> dict[str, str]:
        """Schema name -> the file's header (sign marks stripped; ``none`` = ignore it)."""
        return {name: header.strip().lstrip("-").strip() for name, header in self.columns}

    def dropped(self) -> frozenset[str]:
        """Signals to ignore although the file has them (option ``column``: ``current=none``)."""
        return frozenset(name for name, header in self.columns if header.strip().lower() == "none")

    def declared(self) -> frozenset[str]:
        """Signals whose unit the user stated (the gate then does not second-guess it)."""
        keys = {
            "time": self.time_unit,
            "speed": self.speed_unit,
            "position": self.position_unit,
            "current": self.current_unit,
            "voltage": self.voltage_unit,
        }
        return frozenset(k for k, v in keys.items() if v is not None)

    def negated(self) -> frozenset[str]:
        """Signals whose column is read with the opposite sign (``-HEADER``)."""
        return frozenset(name for name, header in self.columns if header.strip().startswith("-"))

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name == "columns":
                if v:
                    out["columns"] = dict(v)
            elif isinstance(v, enum.Enum):
                out[f.name] = v.value
            elif v is not None:
                out[f.name] = v
        return out


@dataclass(frozen=True)
class LoadedInput:
    """One DATA argument in SI units, with what was done to get there."""

    path: str
    run: Run
    spec: InputSpec
    notes: tuple[str, ...]


# -- the caller's options ---------------------------------------------------------
# the keyword options of spec_from_options beside ``column`` (InputOptions' field names)
UNIT_OPTIONS = (
    *_UNIT_KEYS,
    "supply_v",
    "counts_per_rev",
    "gear_ratio",
    "speed_averaged",
)


def spec_from_options(
    *,
    column: Sequence[str] = (),
    time_unit: str | None = None,
    speed_unit: str | None = None,
    position_unit: str | None = None,
    current_unit: str | None = None,
    voltage_unit: str | None = None,
    supply_v: str | float | None = None,
    counts_per_rev: str | float | None = None,
    gear_ratio: str | float | None = None,
    speed_averaged: bool | None = None,
    origin: str = "command line",
) -> InputSpec:
    """The :class:`InputSpec` of the caller's options (the command line's ``--column``,
    ``--speed-unit``, ...; ``None``: not given); refuses malformed ones
    (:class:`~pmdc_ident.core.errors.DataOptionError`, the option in the caller's words).
    ``column``: ``NAME=HEADER`` items."""
    given = {
        "time_unit": time_unit,
        "speed_unit": speed_unit,
        "position_unit": position_unit,
        "current_unit": current_unit,
        "voltage_unit": voltage_unit,
        "supply_v": supply_v,
        "counts_per_rev": counts_per_rev,
        "gear_ratio": gear_ratio,
    }
    data: dict[str, Any] = {k: v for k, v in given.items() if v is not None}
    if speed_averaged:
        data["speed_averaged"] = True
    cols: dict[str, str] = {}
    for item in column or ():
        name, sep, header = item.partition("=")
        if not sep or not name.strip() or not header.strip():
            why = f"expects NAME=HEADER (e.g. speed=Speed_rpm), got {item!r}"
            raise DataOptionError("column", item, why)
        cols[name.strip().lower()] = header.strip()
    if cols:
        data["columns"] = cols
    return InputSpec.from_mapping(data, origin)


# -- sidecar -----------------------------------------------------------------------
def sidecar_path(data_path: str | Path) -> Path:
    """``RUN.csv`` -> ``RUN.csv.yaml`` (a bag directory ``DIR`` -> ``DIR.yaml``)."""
    return Path(str(Path(data_path)) + ".yaml")


def read_sidecar(data_path: str | Path) -> InputSpec | None:
    """The sidecar YAML of a recording, or ``None`` when it has none."""
    side = sidecar_path(data_path)
    if not side.is_file():
        return None
    import yaml

    from pmdc_ident.core.safe_write import protect

    protect([side], "the sidecar")
    try:
        data = yaml.safe_load(side.read_text(encoding="utf-8"))
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        msg = f"{side}: not a readable YAML file ({first})"
        raise DataError(msg) from None
    if data is None:
        return None
    if not isinstance(data, Mapping):
        msg = f"{side}: expected keys such as 'speed_unit: rpm', got {type(data).__name__}"
        raise DataError(msg)
    return InputSpec.from_mapping(data, str(side))


# -- conversion --------------------------------------------------------------------
def _angle_factor(
    unit: SpeedUnit | PositionUnit | None,
    cpr: float | None,
    what: str,
) -> tuple[float, str]:
    if unit is None:
        return 1.0, ""
    value = unit.value.split("/")[0]
    if value == "counts":
        if cpr is None:
            why = (
                f"{unit.value} needs {opt('counts_per_rev')} N "
                "(`pmdc-ident check` estimates N from the data when it can)"
            )
            raise DataOptionError(f"{what}_unit", unit.value, why)
        return _TWO_PI / cpr, f"{unit.value} at {cpr:g} counts/rev"
    return _ANGLE_FACTOR[value], unit.value


def _factors(spec: InputSpec) -> tuple[dict[str, float], list[str]]:
    """SI factor per signal and the notes saying so (factor 1 is left out)."""
    gear = spec.gear_ratio or 1.0
    f = {"t": 1.0, "voltage": 1.0, "current": 1.0, "position": 1.0, "speed": 1.0}
    notes: list[str] = []
    if spec.time_unit is not None:
        f["t"] = _TIME_FACTOR[spec.time_unit]
    if spec.current_unit is CurrentUnit.MA:
        f["current"] = 1e-3
    if spec.voltage_unit is VoltageUnit.MV:
        f["voltage"] = 1e-3
    elif spec.voltage_unit in (VoltageUnit.DUTY, VoltageUnit.DUTY_PERCENT):
        if spec.supply_v is None:
            why = f"{spec.voltage_unit.value} needs {opt('supply_v')} V"
            raise DataOptionError("voltage_unit", spec.voltage_unit.value, why)
        scale = 1.0 if spec.voltage_unit is VoltageUnit.DUTY else 0.01
        f["voltage"] = spec.supply_v * scale
    f["speed"], speed_from = _angle_factor(spec.speed_unit, spec.counts_per_rev, "speed")
    f["position"], pos_from = _angle_factor(spec.position_unit, spec.counts_per_rev, "position")
    f["speed"] *= gear
    f["position"] *= gear
    units = {"t": "s", "voltage": "V", "current": "A", "position": "rad", "speed": "rad/s"}
    origins = {
        "t": spec.time_unit.value if spec.time_unit else "",
        "current": spec.current_unit.value if spec.current_unit else "",
        "voltage": spec.voltage_unit.value if spec.voltage_unit else "",
        "speed": speed_from,
        "position": pos_from,
    }
    for name, factor in f.items():
        if origins[name] and factor != 1.0:
            notes.append(
                f"{name} converted from {origins[name]} (x {factor:.6g} -> {units[name]})"
            )
    if spec.voltage_unit in (VoltageUnit.DUTY, VoltageUnit.DUTY_PERCENT):
        notes.append(f"voltage = duty x supply {spec.supply_v:g} V (no sag or dead time modelled)")
    if spec.gear_ratio is not None:
        notes.append(
            f"gear ratio {gear:g}: speed and position measured on the load side, "
            "converted to the motor side; parameters are the motor's"
        )
    return f, notes


def scales(spec: InputSpec) -> tuple[dict[str, float], list[str]]:
    """SI factor (sign included) per column, and the notes of what is converted."""
    f, notes = _factors(spec)
    flip = spec.negated()
    for name in sorted(flip):
        notes.append(f"{name} sign flipped (column {dict(spec.columns)[name].strip()})")
    for name in sorted(spec.dropped()):
        notes.append(f"{name} column ignored ({opt('column')} {name}=none)")
    f["terminal_voltage"] = f["voltage"] if spec.voltage_unit is VoltageUnit.MV else 1.0
    out = {name: factor * (-1.0 if name in flip else 1.0) for name, factor in f.items()}
    return out, notes


def convert_run(run: Run, spec: InputSpec) -> tuple[Run, tuple[str, ...]]:
    """``run`` (read in its own units, e.g. a bag) in SI units, with the notes."""
    f, notes = scales(spec)
    drop = spec.dropped()
    if drop:
        run = _drop(run, drop)
    if all(v == 1.0 for v in f.values()):
        return _finish(run, notes, spec)

    def conv(seg: Segment) -> Segment:
        def s(name: str) -> np.ndarray | None:
            arr = getattr(seg, name)
            return None if arr is None else arr * f[name]

        hist_v = seg.history_voltage
        heat = seg.history_heat_a2s
        return replace(
            seg,
            t=seg.t * f["t"],
            voltage=s("voltage"),
            current=s("current"),
            position=s("position"),
            speed=s("speed"),
            terminal_voltage=s("terminal_voltage"),
            history_voltage=None if hist_v is None else hist_v * f["voltage"],
            history_heat_a2s=None if heat is None else heat * f["current"] ** 2 * f["t"],
        )

    return _finish(Run(tuple(conv(s) for s in run.segments), source=run.source), notes, spec)


def _finish(run: Run, notes: list[str], spec: InputSpec) -> tuple[Run, tuple[str, ...]]:
    """Wrapped positions unwrapped; an averaged speed read as the position it sums to; an
    unlabeled log cut where a new run starts (before any unwrapping: a position that
    restarts with a run is not a wrap)."""
    from pmdc_ident.core.segmentation import split_restarts

    if spec.speed_averaged:
        run = _speed_as_counts(run, notes)
    return _unwrap(split_restarts(run), notes)


def _speed_as_counts(run: Run, notes: list[str]) -> Run:
    """Option ``speed_averaged``: a speed that is the counts since the last sample (their mean
    over the interval, half a sample late) becomes the position it sums to; where the
    file has the position too, the speed is dropped."""
    segs = []
    for s in run.segments:
        if s.speed is None:
            segs.append(s)
            continue
        pos = s.position
        if pos is None:
            pos = np.cumsum(s.speed * np.r_[0.0, np.diff(s.t)])
        segs.append(replace(s, speed=None, position=pos))
    notes.append(
        f"speed is the mean over each sample interval ({opt('speed_averaged')}): its running "
        "sum is the encoder's position, which the fit uses instead"
    )
    return Run(tuple(segs), source=run.source)


def _unwrap(run: Run, notes: list[str]) -> tuple[Run, tuple[str, ...]]:
    """Positions that wrap at one turn (2 pi, in SI already) made continuous."""
    from pmdc_ident.core.quality.signals import find_wrap

    segs = []
    for s in run.segments:
        found = find_wrap(s.position) if s.position is not None else None
        if found is not None and abs(found[0] / _TWO_PI - 1.0) < 0.02:
            notes.append(
                f"position wraps at 2 pi in segment {s.label!r} ({found[1]} times): unwrapped"
            )
            s = replace(s, position=np.unwrap(s.position, period=_TWO_PI))
        segs.append(s)
    return Run(tuple(segs), source=run.source), tuple(notes)


def _drop(run: Run, names: frozenset[str]) -> Run:
    if "t" in names or "segment" in names:
        why = "t=none / segment=none: only signal columns can be ignored"
        raise DataOptionError("column", sorted(names), why)
    changes: dict[str, Any] = dict.fromkeys(names)
    if "voltage" in names:
        changes["history_voltage"] = None
    if "current" in names:
        changes["history_heat_a2s"] = None
    try:
        segs = tuple(replace(s, **changes) for s in run.segments)
    except DataError as exc:
        msg = f"{run.source}: cannot ignore {', '.join(sorted(names))}: {exc}"
        raise DataError(msg) from None
    return Run(segs, source=run.source)


# signal -> (the option that states its unit, the units a logger likely wrote)
_UNIT_HINT = {
    "t": ("time_unit", "ms|us|ns"),
    "voltage": ("voltage_unit", "mV"),
    "current": ("current_unit", "mA"),
    "speed": ("speed_unit", "rpm|deg/s|counts/s"),
    "position": ("position_unit", "deg|counts"),
    "terminal_voltage": ("voltage_unit", "mV"),
}


def load_input(path: str | Path, spec: InputSpec | None = None) -> LoadedInput:
    """Read one DATA argument with its sidecar and ``spec`` (command line) applied.

    A CSV is scaled to SI while it is read (before the range checks of
    :class:`~pmdc_ident.core.data.Segment`); a bag is converted after.
    """
    from pmdc_ident.dataio import load_data

    side = read_sidecar(path)
    full = (spec or InputSpec()).merged_over(side)
    p = Path(path)
    if p.is_dir() or p.suffix.lower() == ".mcap":
        if full.columns and any(n not in full.dropped() for n, _ in full.columns):
            msg = f"{p}: {opt('column')} applies to CSV files only (a bag has fixed topics)"
            raise DataError(msg)
        run, notes = convert_run(load_data(path), full)
    else:
        factors, note_list = scales(full)
        try:
            raw = load_data(path, columns=full.column_map() or None, scale=factors)
        except SignalRangeError as exc:
            raise DataError(_with_unit_hint(exc)) from None
        run, notes = _finish(raw, note_list, full)
    if side is not None:
        notes = (f"units and columns from {sidecar_path(path)}", *notes)
    _check_declared(str(path), run, full)
    return LoadedInput(str(path), run, full, notes)


def _check_declared(where: str, run: Run, spec: InputSpec) -> None:
    """A declared unit the other columns contradict is an error (``dataio.declared``)."""
    from pmdc_ident.dataio.declared import check_declared

    volts = [
        np.abs(s.voltage[np.isfinite(s.voltage)]) for s in run.segments if s.voltage is not None
    ]
    v_max = None
    if volts and any(v.size for v in volts):
        factor = abs(scales(spec)[0]["voltage"]) or 1.0
        v_max = float(max(v.max() for v in volts if v.size)) / factor
    check_declared(where, run, spec, v_max)


def _with_unit_hint(exc: SignalRangeError) -> str:
    """A sample beyond any motor test, with the option that states the column's unit."""
    message = str(exc)
    if exc.signal not in _UNIT_HINT:
        return message
    key, units = _UNIT_HINT[exc.signal]
    epoch = _epoch_unit(exc.value) if exc.signal == "t" else None
    if epoch is not None:
        return f"{message} (Unix time in {epoch}: {opt(key)} {epoch})"
    return f"{message} (if the column is in other units, say which: {opt(key)} {units})"


def _epoch_unit(t_s: float) -> str | None:
    """``ms``, ``us`` or ``ns`` when a time ``t_s`` (read as seconds) read in that unit is
    a date between 2001 and 2096 in Unix seconds (a logger's epoch stamps), else None."""
    t = abs(float(f"{t_s:.6g}"))  # as the message shows it
    for unit, factor in (("ms", 1e3), ("us", 1e6), ("ns", 1e9)):
        if 1e9 <= t / factor <= 4e9:
            return unit
    return None
