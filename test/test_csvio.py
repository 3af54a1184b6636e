"""CSV runs: schema, round trip, and one clear line for each kind of bad file."""

from __future__ import annotations

import numpy as np
import pytest

from pmdc_ident.core.data import Run, Segment, TestKind
from pmdc_ident.core.errors import DataError
from pmdc_ident.dataio import load_data
from pmdc_ident.dataio.csvio import read_csv, write_csv


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
