"""Automatic segmentation of one continuous, unlabeled log (independent RK4 records)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers.motor_records import Motor, continuous_voltage, simulate, steps, write_csv

from pmdc_ident.cli import main
from pmdc_ident.core.data import TestKind
from pmdc_ident.core.segmentation import find_segments, segment_run
from pmdc_ident.dataio.units import load_input

RATE = 1000


@pytest.fixture(scope="module")
def continuous(tmp_path_factory):
    """Rest, two steps, a chirp, a PRBS, a hold, an open-armature coast, a step to 0 V."""
    v = continuous_voltage(RATE)
    rec = simulate(Motor(Tc=0.002), v, RATE, substeps=10, noise_current=0.005, noise_speed=0.05)
    return write_csv(tmp_path_factory.mktemp("seg") / "log.csv", rec)


def test_a_continuous_log_is_cut_into_its_experiments(continuous):
    seg = load_input(continuous).run.segments[0]
    pieces = find_segments(seg)
    got = [(p.label, p.start, p.stop) for p in pieces]
    assert [g[0] for g in got] == [
        "plateau_1",
        "step_up_1",
        "step_up_2",
        "sweep_1",
        "prbs_1",
        "step_up_3",
        "coast_1",
        "step_up_4",
    ]
    # boundaries at the command's edges, to the sample
    assert [g[1] for g in got] == [0, 300, 1100, 1900, 4900, 6900, 7700, 9200]
    run, lines = segment_run(load_input(continuous).run)
    assert len(lines) == 8 and lines[3].startswith("sweep_1 1.9-4.899 s (3000 samples")
    kinds = [s.kind for s in run.segments]
    assert kinds[1] is TestKind.STEP and kinds[3] is TestKind.SWEEP and kinds[6] is TestKind.COAST
    # each piece carries the commands before it (the fit simulates it from its start)
    assert run.segments[2].history_voltage is not None
    assert run.segments[2].history_voltage.size == 1100


def test_identify_prints_the_segments_and_recovers_the_motor(continuous, capsys):
    rc = main(["identify", str(continuous), "--quiet", "--no-holdout", "--json", "-"])
    cap = capsys.readouterr()
    assert rc == 0
    assert "segments found in" in cap.err and "  prbs_1 4.9-6.899 s" in cap.err
    import json

    data = json.loads(cap.out)
    truth = {"R": 2.0, "L": 2e-3, "Ke": 0.05, "J": 2e-5}
    for name, value in truth.items():
        assert data["parameters"][name]["value"] == pytest.approx(value, rel=0.005), name


def test_a_step_already_on_at_the_first_sample_is_a_step(tmp_path):
    rec = simulate(Motor(), np.full(600, 8.0), RATE, substeps=10, noise_current=0.005)
    run, lines = segment_run(load_input(write_csv(tmp_path / "on.csv", rec)).run)
    assert [s.label for s in run.segments] == ["step_up_1"]
    assert lines == ["step_up_1 0-0.599 s (600 samples, 8 V)"]


def test_labelled_files_and_the_option_keep_their_segments(continuous, tmp_path, capsys):
    rec = simulate(Motor(), steps([6, 12], 0.3, RATE), RATE, substeps=10)
    rec.labels = ["a"] * 300 + ["b"] * 300
    labelled = load_input(write_csv(tmp_path / "lab.csv", rec)).run
    assert segment_run(labelled)[0] is labelled
    rc = main(["check", str(continuous), "--no-auto-segments"])
    assert rc == 0 and "segments found" not in capsys.readouterr().out


def test_a_few_short_holds_do_not_break_the_segmentation():
    """Found by the property test over CSVs: 11 rest rows, then 8 rows of a ramp."""
    from pmdc_ident.core.data import Run, Segment

    t = np.arange(19) * 1e-3
    current = np.r_[np.zeros(11), [8.62, 8.68, 8.65, 8.63, 8.60, 8.57, 8.54, 8.52]]
    speed = np.r_[np.zeros(11), np.linspace(0.44, 4.36, 8)]
    run = Run((Segment("run", t, None, current=current, speed=speed),))
    segmented, lines = segment_run(run)
    assert sum(s.n for s in segmented.segments) == 19


def test_contiguous_pieces_cut_at_gaps_and_drop_stubs():
    from pmdc_ident.core.data import Segment
    from pmdc_ident.core.segmentation import contiguous_pieces

    t = np.r_[np.arange(100), np.arange(150, 160), np.arange(200, 300)] * 1e-3
    v = np.where(t < 0.05, 0.0, 6.0)
    seg = Segment("step_up", t, v, current=np.sin(t), speed=np.cos(t), history_voltage=v[:3])
    pieces, gaps = contiguous_pieces(seg, min_samples=21)
    assert gaps == 2
    assert [p.label for p in pieces] == ["step_up.1", "step_up.2"]  # the 10-sample stub left
    assert [p.n for p in pieces] == [100, 100] and pieces[1].t[0] == pytest.approx(0.2)
    assert pieces[0].history_voltage is not None  # the record before it is still contiguous
    assert pieces[1].history_voltage is None  # the commands across a gap have no timing


def test_found_segments_are_holdout_labels_for_diagnose(continuous, tmp_path, capsys):
    js = tmp_path / "d.json"
    argv = ["diagnose", str(continuous), "--holdout", "step_up_2", "--quiet"]
    rc = main([*argv, "--effects", "coulomb_friction", "--json", str(js)])
    assert rc == 0, capsys.readouterr().err
    split = json.loads(js.read_text())["holdout"]
    assert split["rule"] == "user" and split["held_out_segments"] == ["step_up_2"]
    assert "step_up_2" not in split["fit_segments"] and "sweep_1" in split["fit_segments"]
