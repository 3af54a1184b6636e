"""CSV runs: schema, round trip, and one clear line for each kind of bad file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pmdc_ident.core.data import Run, Segment, TestKind
from pmdc_ident.core.errors import DataError
from pmdc_ident.dataio import load_data
from pmdc_ident.dataio.csvio import read_csv, write_csv

FIXTURES = Path(__file__).parent / "fixtures"


def _write(tmp_path, text: str, name: str = "run.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_round_trip_keeps_values_segments_and_open_armature(tmp_path):
    t = np.arange(5) * 1e-3
    v = np.array([1.0, 2.0, np.nan, np.nan, 0.5])
    segs = (
        Segment("step_up", t, np.full(5, 3.25), current=np.linspace(0, 1, 5), speed=t * 7),
        Segment("coast", t + 1.0, v, current=np.zeros(5), speed=np.ones(5) / 3),
    )
    p = write_csv(Run(segs, "x"), tmp_path / "r.csv")
    back = load_data(p)
    assert back.labels == ("step_up", "coast")
    assert back.segments[1].kind is TestKind.COAST
    for a, b in zip(segs, back.segments, strict=True):
        np.testing.assert_array_equal(a.t, b.t)
        np.testing.assert_array_equal(a.current, b.current)
        np.testing.assert_array_equal(a.speed, b.speed)
        np.testing.assert_array_equal(np.isnan(a.voltage), np.isnan(b.voltage))
    assert back.segments[1].open_mask.tolist() == [False, False, True, True, False]


def test_header_case_comments_and_no_segment_column(tmp_path):
    p = _write(tmp_path, "# note\n T , Voltage,Position\n0,1,0\n0.001,1,0.01\n0.002,1,0.03\n")
    run = read_csv(p)
    assert run.labels == ("run",)
    assert run.segments[0].speed is None
    assert run.segments[0].position[-1] == pytest.approx(0.03)


def test_without_voltage_column_the_run_is_current_driven(tmp_path):
    p = _write(tmp_path, "t,current,speed\n0,1,0\n0.001,1,0.5\n")
    seg = read_csv(p).segments[0]
    assert seg.voltage is None and seg.current is not None


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("voltage,current,speed\n1,2,3\n2,3,4\n", "missing column 't'"),
        ("t,voltage,current\n0,1,2\n1,1,2\n", "'position' or 'speed'"),
        ("t,voltage,speed\n0,1,2\n0.1,abc,2\n", "line 3: 'voltage' is not a number"),
        ("t,voltage,speed\n0,1,2\n0,1,2\n", "line 3: time does not increase"),
        ("t,voltage,speed\n0,1,2\n-1,1,2\n", "time does not increase"),
        ("t,voltage,speed\n0,1,2\n0.1,1,nan\n", "line 3: 'speed' is 'nan'"),
        ("t,voltage,speed\n0,1,2\n0.1,NaN,2\n", "empty to mark an open armature"),
        ("t,voltage,speed\n0,1,2\n0.1,1,\n", "empty 'speed' cell"),
        ("t,voltage,speed\n", "header only"),
        ("", "empty file"),
        ("t,voltage,speed,speed\n0,1,2,2\n", "repeated column"),
        ("t,voltage,speed,segment\n0,1,2,a\n1,1,2,b\n", "only one sample"),
    ],
)
def test_bad_files_give_one_line_naming_the_problem(tmp_path, text, match):
    p = _write(tmp_path, text)
    with pytest.raises(DataError, match=match) as info:
        read_csv(p)
    assert "\n" not in str(info.value)


def test_binary_file_is_refused(tmp_path):
    p = tmp_path / "b.csv"
    p.write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(DataError, match="not a text"):
        read_csv(p)


def _plain_text(n: int = 400) -> str:
    """A logger's plain file: segment label in the middle column, open (empty) voltage
    cells, spaces around a few numbers."""
    rng = np.random.default_rng(3)
    rows = ["time,Voltage,segment,current,speed"]
    for k in range(n):
        v = "" if 150 <= k < 250 else repr(float(rng.normal(6, 1)))
        label = "coast" if 150 <= k < 250 else ("up" if k < 150 else "down")
        i, w = (repr(float(x)) for x in rng.normal(size=2))
        rows.append(f"{k * 1e-3!r},{v},{label},{' ' + i if k % 7 == 0 else i},{w}")
    return "\n".join(rows) + "\n"


def test_plain_files_take_the_fast_reader_and_match_the_careful_one(tmp_path):
    from pmdc_ident.dataio import csvio

    cols = {"t": "time"}
    for p in (_write(tmp_path, _plain_text()), *sorted(FIXTURES.glob("*.csv"))):
        text = csvio._text(p)
        fast = csvio._fast_table(p, cols if p.parent == tmp_path else {})
        careful = csvio._careful_table(p, text, cols if p.parent == tmp_path else {})
        assert fast is not None, p  # a plain file: numpy's C parser
        assert fast[0].keys() == careful[0].keys()
        for name, arr in fast[0].items():
            np.testing.assert_array_equal(arr, careful[0][name], err_msg=f"{p} {name}")
        assert list(fast[1]) == list(careful[1]) and list(fast[2]) == list(careful[2])


ODD = {
    "a comment line": lambda lines: lines.insert(200, "# the rig was re-zeroed here"),
    "a blank line": lambda lines: lines.insert(100, ""),
    "quoted cells": lambda lines: lines.__setitem__(5, lines[5].replace(",up,", ',"up",')),
    "a trailing separator": lambda lines: lines.__setitem__(9, lines[9] + ","),
}


@pytest.mark.parametrize("case", sorted(ODD))
def test_odd_files_take_the_careful_reader_with_the_same_result(case, tmp_path):
    from pmdc_ident.dataio import csvio

    lines = _plain_text().splitlines()
    plain = read_csv(_write(tmp_path, "\n".join(lines) + "\n", "plain.csv"), {"t": "time"})
    ODD[case](lines)
    odd = _write(tmp_path, "\n".join(lines) + "\n", "odd.csv")
    assert csvio._fast_table(odd, {"t": "time"}) is None
    back = read_csv(odd, {"t": "time"})
    assert back.labels == plain.labels
    for a, b in zip(back.segments, plain.segments, strict=True):
        np.testing.assert_array_equal(a.current, b.current)
        np.testing.assert_array_equal(a.voltage, b.voltage)


@pytest.mark.parametrize(
    ("cell", "match"),
    [
        ("nan", "'voltage' is 'nan'"),
        ("inf", "'voltage' is 'inf'"),
        ("6 V", "'voltage' is not a number"),
    ],
)
def test_a_bad_cell_in_a_plain_file_names_its_line(cell, match, tmp_path):
    lines = _plain_text().splitlines()
    head, _v, rest = lines[300].split(",", 2)
    lines[300] = f"{head},{cell},{rest}"  # file line 301
    p = _write(tmp_path, "\n".join(lines) + "\n")
    with pytest.raises(DataError, match=f"line 301: {match}"):
        read_csv(p, {"t": "time"})
