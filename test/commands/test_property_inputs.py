"""Property test over inputs: whatever CSV or bag a user hands over, every command
exits 0 or 2, never prints a traceback or a warning, and never exits 0 on data
that break a rule the documentation states (docs/reference.md, docs/user-guide.md).

Generated CSVs: random column subsets and orders (repeated and unknown columns
too), NaN/inf/empty/non-numeric cells, repeated or reversed time, huge and tiny
values, random segment labels, and truncation at any byte. Bags: a recorded
session truncated at any byte, as a bag folder and as a bare ``.mcap``.

The rules are checked by :func:`broken_rule`, written from the documentation, not from
the reader's code. The default profile keeps the file to a few seconds; set
``PMDC_PROPERTY_EXAMPLES=500`` (or more) for a long hunt.
"""

from __future__ import annotations

import functools
import itertools
import math
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.model import simulate
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio.bagio import write_bag

EXAMPLES = int(os.environ.get("PMDC_PROPERTY_EXAMPLES", "0")) or None
CSV_EXAMPLES = EXAMPLES or 30
BAG_EXAMPLES = EXAMPLES or 12
SETTINGS = {
    "deadline": None,
    "derandomize": EXAMPLES is None,  # the default run is the same on every machine
    # capsys is read (and so emptied) after every command
    "suppress_health_check": [
        HealthCheck.too_slow,
        HealthCheck.data_too_large,
        HealthCheck.function_scoped_fixture,
    ],
}

# The CSV schema and limits (docs/reference.md "CSV runs"), restated for the oracle.
NUMERIC = ("t", "voltage", "current", "position", "speed", "terminal_voltage")
LIMITS = {
    "t": 4e9,
    "voltage": 1e5,
    "current": 1e5,
    "position": 1e12,
    "speed": 1e6,
    "terminal_voltage": 1e5,
}
MIN_STEP_S = 1e-9


def broken_rule(text: str) -> str | None:
    """The first documented rule the CSV ``text`` breaks, or None."""
    lines = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not lines:
        return "empty file"
    header = [h.strip().lower() for h in lines[0].split(",")]
    named = [h for h in header if h]
    if len(set(named)) != len(named):
        return "repeated column"
    if "t" not in header:
        return "no t"
    if "speed" not in header and "position" not in header:
        return "no speed or position"
    if "voltage" not in header and "current" not in header:
        return "no voltage or current"
    rows = [ln.split(",") for ln in lines[1:]]
    if not rows:
        return "header only"
    columns: dict[str, list[float]] = {h: [] for h in header if h in NUMERIC}
    labels = []
    for row in rows:
        extra = row[len(header) :]
        if len(row) < len(header) or any(c.strip() for c in extra):
            return "cells do not match the header"
        for name, cell in zip(header, row, strict=False):
            cell = cell.strip()
            if name == "segment":
                labels.append(cell)
            if name not in NUMERIC:
                continue
            if cell == "" and name == "voltage":
                columns[name].append(math.nan)
                continue
            try:
                value = float(cell)
            except ValueError:
                return f"{name} not a number"
            if not math.isfinite(value) or abs(value) > LIMITS[name]:
                return f"{name} not finite or beyond its limit"
            columns[name].append(value)
    dt = np.diff(columns["t"])
    if (dt <= 0).any():
        return "time does not increase"
    if (dt < MIN_STEP_S).any():
        return "samples closer than 1 ns"
    if labels:
        sizes = [len(list(g)) for _, g in itertools.groupby(labels)]
        if min(sizes) < 2:
            return "a segment of one sample"
    elif len(rows) < 2:
        return "one sample"
    return None


# ---------------------------------------------------------------------------
# generated CSVs
# ---------------------------------------------------------------------------
def _base_signals(n: int = 60, dt: float = 1e-3) -> dict[str, np.ndarray]:
    """A physically consistent step and coast of the seed-000 motor."""
    spec = load_motor("seed000_ebike")
    v = np.full(n, 12.0)
    v[: n // 6] = 0.0
    v[2 * n // 3 :] = np.nan  # the armature opened: a coast-down
    sim = simulate(spec.model, v, dt)
    return {
        "voltage": v,
        "current": sim.current,
        "position": sim.position,
        "speed": sim.speed,
        "terminal_voltage": np.where(np.isnan(v), 0.0, v) * 0.98,
    }


@functools.cache
def _base() -> dict[str, np.ndarray]:
    """:func:`_base_signals`, simulated at the first draw, not when the module is imported
    (every test process collects this module; on a fresh clone the simulation compiled
    the model's kernels in each of them)."""
    return _base_signals()


COLUMN_CHOICES = ("t", "voltage", "current", "position", "speed", "terminal_voltage", "segment")
ODD_CELLS = ("nan", "NaN", "inf", "-inf", "", " ", "1e300", "-1e300", "1e-300", "abc", "0x1p3")


@st.composite
def csv_texts(draw) -> str:
    # the coin for each kind of damage: hypothesis' own draws lean to their bounds,
    # which would damage nearly every file
    coin = draw(st.randoms(use_true_random=False))

    def _sometimes(_draw, one_in: int) -> bool:
        return coin.random() < 1.0 / one_in

    n = draw(st.integers(2, 60))
    if _sometimes(draw, 5):  # any columns at all
        cols = list(draw(st.permutations(COLUMN_CHOICES)))
        cols = cols[: draw(st.integers(1, len(cols)))]
    else:  # a schema that holds what a fit needs, in any order
        cols = ["t", draw(st.sampled_from(["voltage", "current"]))]
        cols.append(draw(st.sampled_from(["speed", "position"])))
        cols += draw(st.lists(st.sampled_from(COLUMN_CHOICES[1:]), unique=True, max_size=4))
        cols = list(draw(st.permutations(list(dict.fromkeys(cols)))))
    if _sometimes(draw, 6):
        cols.append(draw(st.sampled_from(["comment", "rpm", cols[0]])))  # unknown or repeated
    dt = draw(st.sampled_from([1e-3, 1e-3, 2e-2, 0.6, 1e-300]))
    t = draw(st.sampled_from([0.0, -5.0, 1.7e9])) + dt * np.arange(n)
    if _sometimes(draw, 6):
        t = _bad_time(draw, t)
    signals = {name: _base()[name][:n].copy() for name in _base()}
    if _sometimes(draw, 6):  # one column in other units, or garbage magnitude
        name = draw(st.sampled_from(sorted(signals)))
        signals[name] = signals[name] * draw(st.sampled_from([1e300, 1e-300, 1e6, -1.0, 0.0]))
    n_blocks = draw(st.integers(1, 3))
    cuts = sorted(draw(st.lists(st.integers(1, n - 1), min_size=n_blocks - 1, max_size=n_blocks)))
    names = draw(
        st.lists(st.sampled_from(["step", "coast", "sweep_1", "", "a b", "é"]), min_size=4)
    )
    labels = [names[int(np.searchsorted(cuts, k, side="right"))] for k in range(n)]
    odd_cells = {}
    if _sometimes(draw, 4):
        cell = st.tuples(st.integers(0, n - 1), st.sampled_from(cols), st.sampled_from(ODD_CELLS))
        odd_cells = {(r, c): v for r, c, v in draw(st.lists(cell, min_size=1, max_size=2))}
    lines = [",".join(cols)]
    for k in range(n):
        row = []
        for c in cols:
            if (k, c) in odd_cells:
                row.append(odd_cells[(k, c)])
            elif c == "t":
                row.append(repr(float(t[k])))
            elif c == "segment":
                row.append(labels[k])
            elif c in signals:
                x = float(signals[c][k])
                row.append("" if math.isnan(x) else repr(x))
            else:
                row.append("1")
        lines.append(",".join(row))
    text = "\n".join(lines) + "\n"
    if _sometimes(draw, 4):  # truncated at any byte
        data = text.encode()
        text = data[: draw(st.integers(0, len(data)))].decode("utf-8", errors="ignore")
    return text


def _bad_time(draw, t: np.ndarray) -> np.ndarray:
    n = t.size
    match draw(st.sampled_from(["repeat", "reverse", "swap", "restart"])):
        case "repeat":
            k = draw(st.integers(1, n - 1))
            t[k] = t[k - 1]
        case "reverse":
            t = t[::-1].copy()
        case "swap" if n > 2:
            k = draw(st.integers(1, n - 2))
            t[k], t[k + 1] = t[k + 1], t[k]
        case "restart":  # a second run on its own clock
            k = draw(st.integers(1, n - 1))
            t[k:] -= t[k]
    return t


def _run(argv: list[str], capsys, caplog=None) -> tuple[int, str, str]:
    """Exit status, stdout and stderr of ``pmdc-ident argv`` (log notes count as stderr:
    without pytest's log capture they reach the terminal there)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc = main(argv)
    out, err = capsys.readouterr()
    if caplog is not None:
        err = "".join(f"{r.getMessage()}\n" for r in caplog.records) + err
        caplog.clear()
    assert not caught, f"{argv}: warning {caught[0].category.__name__}: {caught[0].message}"
    return rc, out, err


def _check_outcome(command: str, rc: int, out: str, err: str) -> None:
    assert rc in (0, EXIT_USER_ERROR), f"{command}: exit {rc}\n{err}"
    assert "Traceback" not in err and "Warning" not in err, err
    if rc == EXIT_USER_ERROR:
        # one error line; above it only the data-quality gate's findings or a note
        # on what a cut-off bag lost
        *above, last = err.strip().splitlines()
        assert last.startswith(f"pmdc-ident {command}: error:"), err
        for line in above:
            assert line == "data quality:" or line.startswith("  ") or "truncated" in line, err


@settings(max_examples=CSV_EXAMPLES, **SETTINGS)
@given(text=csv_texts())
def test_any_csv_gives_exit_0_or_one_line_and_2(text, capsys):
    rule = broken_rule(text)
    event(f"csv: {rule or 'valid'}")
    with tempfile.TemporaryDirectory(prefix="pmdc_prop_") as tmp:
        p = Path(tmp) / "run.csv"
        p.write_text(text)
        rc, out, err = _run(["export", str(p), "--bag", str(Path(tmp) / "bag")], capsys)
        _check_outcome("export", rc, out, err)
        if rule is not None:
            assert rc == EXIT_USER_ERROR, f"exit 0 although the file breaks: {rule}\n{text}"
        else:
            assert rc == 0, f"a valid file was refused:\n{err}\n{text}"
        for command in ("identify", "diagnose"):
            rc, out, err = _run([command, str(p), "--quiet"], capsys)
            _check_outcome(command, rc, out, err)
            event(f"{command}: exit {rc}")
            if rule is not None:
                assert rc == EXIT_USER_ERROR, f"{command} exit 0 although: {rule}\n{text}"


# ---------------------------------------------------------------------------
# truncated bags
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def recorded_bag(tmp_path_factory) -> Path:
    spec = load_motor("seed001_110v")
    cfg = SequenceConfig(
        staircase_levels=2,
        staircase_hold_tau=2.0,
        step_hold_tau=2.0,
        sweep_duration_tau=4.0,
        coast_spinup_tau=2.0,
        coast_open_s=0.05,
    )
    run = synthesize_run(spec.model, plan_for_motor(spec, 5e-3, cfg), spec.sensors, seed=1)
    return write_bag(run, tmp_path_factory.mktemp("bag") / "session")


@settings(max_examples=BAG_EXAMPLES, **SETTINGS)
@given(fraction=st.floats(0.0, 1.0), bare=st.booleans())
def test_any_truncated_bag_gives_exit_0_or_one_line_and_2(
    recorded_bag, fraction, bare, capsys, caplog
):
    [mcap] = sorted(recorded_bag.glob("*.mcap"))
    size = mcap.stat().st_size
    keep = int(fraction * size)
    with tempfile.TemporaryDirectory(prefix="pmdc_prop_") as tmp:
        if bare:
            data = Path(tmp) / "session.mcap"
            shutil.copyfile(mcap, data)
            cut = data
        else:
            data = Path(tmp) / "session"
            shutil.copytree(recorded_bag, data)
            cut = data / mcap.name
        with cut.open("r+b") as fh:
            fh.truncate(keep)
        results = {}
        for command in ("export", "identify", "diagnose"):
            argv = [command, str(data), "--quiet"]
            if command == "export":
                argv = [command, str(data), "--csv", str(Path(tmp) / "out.csv")]
            rc, out, err = _run(argv, capsys, caplog)
            _check_outcome(command, rc, out, err)
            event(f"bag {command}: exit {rc}")
            results[command] = (rc, out + err)
        rc, text = results["export"]
        if rc == 0 and keep < size:  # what a cut-off bag gives back, it must say so
            assert "lost" in text or "truncat" in text, text
