"""Completeness of a session's driver samples on the stamp grid (pure numpy, no ROS)."""

from __future__ import annotations

import numpy as np

from pmdc_ident.dataio.completeness import completeness, topic_completeness

DT = 1_000_000
START = 1_795_000_000_000_000_000  # a real ROS-time stamp: int64 arithmetic must hold


def test_a_full_grid_is_complete_and_says_so_in_one_line():
    s = START + DT * np.arange(4000)
    c = completeness({"current": s, "encoder": s[::-1]}, START, START + 4000 * DT, DT)
    assert c.missing == 0
    assert c.line() == "all 4000 driver samples of the session present on every topic"
    assert c.to_dict()["topics"]["encoder"] == {
        "expected": 4000,
        "present": 4000,
        "missing": 0,
        "gaps_s_n": [],
    }


def test_holes_are_counted_and_located_in_seconds_from_the_start():
    s = START + DT * np.arange(4000)
    lost = np.r_[0:3, 1500:1760, 3999]  # first samples, a 0.26 s stall, the last one
    t = topic_completeness("voltage_applied", np.delete(s, lost), START, START + 4000 * DT, DT)
    assert (t.expected, t.present, t.missing) == (4000, 4000 - lost.size, lost.size)
    assert t.gaps == ((0.0, 3), (1.5, 260), (3.999, 1))
    c = completeness({"voltage_applied": np.delete(s, lost), "encoder": s}, START, s[-1] + DT, DT)
    assert c.missing == lost.size
    assert c.line() == (
        "driver samples missing: voltage_applied 264 of 4000 (3 at 0.000 s, 260 at 1.500 s, "
        "1 at 3.999 s)"
    )


def test_samples_outside_the_session_and_duplicates_do_not_count():
    s = START + DT * np.arange(-50, 1050)
    s = np.r_[s, s[100:200]]  # delivered twice
    t = topic_completeness("encoder", s, START, START + 1000 * DT, DT)
    assert (t.expected, t.present, t.gaps) == (1000, 1000, ())


def test_nothing_received_is_all_missing():
    t = topic_completeness("current", [], START, START + 10 * DT, DT)
    assert (t.missing, t.gaps) == (10, ((0.0, 10),))
