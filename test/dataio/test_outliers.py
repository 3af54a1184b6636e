"""Isolated outliers are found, reported with their lines, and fitted around only on request.

One 1000 A current glitch among 2000 samples gave R -76 % and J +330 % with exit 0
(issue 28). Records from an independent RK4 motor (``helpers.motor_records``).
"""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from helpers.motor_records import Motor, prbs, simulate, steps, write_csv

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.data import Run
from pmdc_ident.dataio.csvio import read_csv

RATE = 1000.0
MOTOR = Motor()


def _voltage() -> np.ndarray:
    v = np.concatenate([steps([6.0, 12.0, -8.0, 0.0, 10.0], 0.3, RATE), prbs(600, 8.0, 1)])
    return np.concatenate([v, np.full(300, np.nan), steps([5.0], 0.2, RATE)])  # a coast


@pytest.fixture(scope="module")
def record():
    return simulate(
        MOTOR, _voltage(), RATE, noise_current=0.002, noise_speed=0.05, counts_per_rev=1024
    )


def test_the_running_median_is_the_median_of_five():
    from numpy.lib.stride_tricks import sliding_window_view

    from pmdc_ident.dataio.outliers import _median5

    rng = np.random.default_rng(0)
    for n in (1, 4, 5, 9, 200):
        x = rng.normal(size=n)
        ref = np.median(sliding_window_view(np.pad(x, 2, mode="edge"), 5), axis=1)
        assert np.array_equal(_median5(x), ref)


def test_a_clean_record_has_no_outlier(record, tmp_path):
    """Steps, one-sample PRBS pulses, a quantised encoder, an open-armature coast."""
    from pmdc_ident.dataio.outliers import find_outliers

    run = read_csv(write_csv(tmp_path / "clean.csv", record))
    assert find_outliers(run) == []


@pytest.mark.parametrize("signal, value", [("current", 1000.0), ("speed", -5e3)])
def test_a_glitch_is_an_error_naming_its_line(record, tmp_path, capsys, signal, value):
    k = 1234
    rec = copy.deepcopy(record)
    getattr(rec, signal)[k] = value
    path = write_csv(tmp_path / "glitch.csv", rec)
    assert main(["check", str(path)]) == EXIT_USER_ERROR
    out = capsys.readouterr()
    line = next(x for x in out.out.splitlines() if "outlier" in x)
    assert line.strip().startswith("error: outlier") and f"line {k + 2} " in line, line
    assert "--drop-outliers" in line
    assert main(["identify", str(path), "--quiet"]) == EXIT_USER_ERROR
    assert "outlier" in capsys.readouterr().err


def test_fitted_around_only_on_request(tmp_path, capsys):
    v = np.concatenate([steps([6.0, 12.0, -8.0, 0.0, 10.0], 0.3, RATE), prbs(500, 8.0, 3)])
    rec = simulate(MOTOR, v, RATE, noise_current=0.002, noise_speed=0.05, seed=3)
    rec.current[1234] = 1000.0
    path = write_csv(tmp_path / "glitch.csv", rec)
    out = tmp_path / "r.json"
    argv = ["identify", str(path), "--quiet", "--drop-outliers", "--json", str(out)]
    assert main(argv) == 0
    doc = json.loads(out.read_text())
    for name in ("R", "Ke", "J"):
        truth = getattr(MOTOR, name)
        assert abs(doc["parameters"][name]["value"] / truth - 1) < 0.005, name
    codes = [f["code"] for f in doc["quality"]["findings"]]
    assert "outlier" in codes  # said, as a warning


def test_a_segment_that_starts_in_the_previous_segment_s_sweep_is_not_a_glitch():
    """A session's marker a few samples late: the coast starts with the sweep's last
    levels (7.75, 7.75, 6.18 V) before its 24 V spin-up; 6.18 V is in the sweep's range
    (the history), so it is a command. The same dip in a steady 24 V is a glitch."""
    from pmdc_ident.core.data import Segment
    from pmdc_ident.dataio.outliers import find_outliers

    rng = np.random.default_rng(1)
    n = 4000  # the lead-in is < 0.5 % of the samples: outside the range of the rest
    t = np.arange(n) / RATE
    v = np.concatenate([[7.749, 7.749, 6.179], np.full(n - 3, 24.0)])
    i = 9.7 + 0.01 * rng.normal(size=n)
    sweep = 10.0 + 5.0 * np.sin(np.arange(500) * 0.3)  # 5 .. 15 V
    coast = Segment("coast", t, v, i, speed=np.linspace(0, 300, n), history_voltage=sweep)
    assert find_outliers(Run((coast,), "session")) == []
    dip = v.copy()
    dip[2000] = 6.179  # far outside 24 V and its own last 50 samples
    glitch = Segment("coast", t, dip, i, speed=np.linspace(0, 300, n), history_voltage=sweep)
    assert [(o.signal, o.index) for o in find_outliers(Run((glitch,), "x"))] == [("voltage", 2000)]
    # and without the history, the lead-in is judged on the segment alone (as before)
    alone = Segment("coast", t, v, i, speed=np.linspace(0, 300, n))
    assert [o.index for o in find_outliers(Run((alone,), "x"))] == [2]
