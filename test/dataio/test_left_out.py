"""Left out means left out (issue 28, item 2; issue 24's "re-identified without saying so").

A segment the reader reports cut short is not fitted, exported or checked; a bag whose
session was interrupted or whose file was cut says so in the result; a topic at half
the rate of the others is joined by stamp without thinning the others out.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.data import Run
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.markers import Marker, MarkerEvent
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio import bagio
from pmdc_ident.dataio.bagio import TOPIC_TYPES, BagWriter, write_bag
from pmdc_ident.dataio.mcap_recover import scan_mcap

SHORT = SequenceConfig(
    staircase_levels=3, staircase_hold_tau=3.0, step_hold_tau=3.0, sweep_duration_tau=10.0
)
TOPICS = {k: v for k, v in TOPIC_TYPES.items() if k != "voltage_cmd"}


class _WriteClock:
    """bagio's clock while a fixture writes: 1 ms per call, a chunk every ~N writes."""

    def __init__(self) -> None:
        self.t = 0.0

    def monotonic(self) -> float:
        self.t += 1e-3
        return self.t


@pytest.fixture(scope="module")
def seed000_run() -> Run:
    spec = load_motor("seed000_ebike")
    return synthesize_run(spec.model, plan_for_motor(spec, 1e-3, SHORT), spec.sensors, seed=1)


@pytest.fixture(scope="module")
def chunked_bag(tmp_path_factory, seed000_run) -> Path:
    """The session in small chunks (one every 0.1 s of writes)."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bagio, "time", _WriteClock())
        return write_bag(seed000_run, tmp_path_factory.mktemp("bag") / "s", flush_s=0.1)


def _copy(src: Path, dst: Path, keep=lambda topic, k, raw: True, extra=()) -> Path:
    """A bag rewritten message by message (``keep`` filters; ``extra`` appended)."""
    from rosbags.rosbag2 import Reader

    counts: dict[str, int] = {}
    with Reader(src) as r, BagWriter(dst, TOPICS) as w:
        for c, t, raw in r.messages():
            counts[c.topic] = counts.get(c.topic, 0) + 1
            if keep(c.topic, counts[c.topic], raw):
                w.write_raw(c.topic, t, raw)
        for topic, t, msg in extra:
            w.write_msg(topic, t, msg)
    return dst


def _cut(src: Path, n: int, where: Path) -> Path:
    where.mkdir()
    (where / "cut.mcap").write_bytes(next(src.glob("*.mcap")).read_bytes()[:n])
    return where


def _first_segment_cut(bag: Path, run: Run) -> int:
    """A byte offset after a complete chunk that holds samples of the first segment only."""
    rec = scan_mcap(next(bag.glob("*.mcap")))
    first = run.segments[0]
    per_sample = 3  # current, encoder, voltage_applied
    for end, n in rec.chunk_ends:
        if per_sample * 10 < n < per_sample * (first.n - 10):
            return end + 5
    raise AssertionError("no chunk boundary inside the first segment")


def test_a_bag_cut_inside_its_first_segment_is_not_fitted_exported_or_checked(
    chunked_bag, seed000_run, tmp_path, capsys
):
    bag = _cut(chunked_bag, _first_segment_cut(chunked_bag, seed000_run), tmp_path / "cut")
    first = seed000_run.segments[0].label
    for argv in (
        ["identify", str(bag), "--quiet"],
        ["export", str(bag), "--csv", str(tmp_path / "out.csv")],
        ["check", str(bag)],
        ["diagnose", str(bag), "--quiet"],
    ):
        rc = main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == EXIT_USER_ERROR, (argv, err)
        assert "no complete segment" in err[-1] and repr(first) in err[-1], err
    assert not (tmp_path / "out.csv").exists()


def test_the_result_says_its_bag_was_cut_and_which_segments_are_missing(
    chunked_bag, seed000_run, tmp_path, capsys
):
    rec = scan_mcap(next(chunked_bag.glob("*.mcap")))
    third = seed000_run.segments[2]
    n_before = 3 * sum(s.n for s in seed000_run.segments[:2])
    end = next(e for e, n in rec.chunk_ends if n > n_before + 3 * (third.n // 2))
    bag = _cut(chunked_bag, end + 3, tmp_path / "cut")
    out = tmp_path / "r.json"
    argv = ["identify", str(bag), "--quiet", "--no-holdout", "--json", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    doc = json.loads(out.read_text())
    state = doc["recording"][str(bag)]
    assert doc["recording_complete"] is False and state["complete"] is False
    assert state["segments_left_out"] == [third.label]
    assert "truncated bag" in state["truncated"] and "no end marker" in state["interrupted"]
    assert third.label not in doc["fit"].get("segments", [])
    assert "recording incomplete" in text


def test_an_aborted_session_is_re_identified_saying_so(chunked_bag, seed000_run, tmp_path):
    """A closed bag of an aborted session: the segment open at the abort is left out and
    the result names the abort (the recorder closes such a bag cleanly)."""
    ts = bagio._typestore()
    String = ts.types[bagio.STRING]
    labels = [s.label for s in seed000_run.segments]
    stop = labels[3]
    cut_ns = round(float(seed000_run.segments[3].t[100]) * 1e9)

    def keep(topic: str, _k: int, raw: bytes) -> bool:
        if topic == "segment":
            m = Marker.from_json(ts.deserialize_cdr(raw, bagio.STRING).data)
            late = round(m.t_s * 1e9) > cut_ns
            return not late and not (m.event is MarkerEvent.END and m.label == stop)
        return bagio.header_stamp_ns(raw) <= cut_ns

    abort = Marker(MarkerEvent.ABORT, "", cut_ns * 1e-9, "export", "peer_crashed")
    end = Marker(MarkerEvent.SESSION_END, "", cut_ns * 1e-9, "export", "peer_crashed")
    extra = [("segment", cut_ns, String(data=m.to_json())) for m in (abort, end)]
    bag = _copy(chunked_bag, tmp_path / "aborted", keep, extra)
    out = tmp_path / "r.json"
    assert main(["identify", str(bag), "--quiet", "--no-holdout", "--json", str(out)]) == 0
    state = json.loads(out.read_text())["recording"][str(bag)]
    assert state["complete"] is False
    assert "aborted: peer_crashed" in state["interrupted"]
    assert state["segments_left_out"] == [stop] and stop not in state["segments"]


def test_a_topic_at_half_the_rate_is_joined_without_dropping_the_others(
    chunked_bag, tmp_path, capsys
):
    """/current every other sample: the old join kept half of every topic (R +4 %,
    J -4 %, outside their intervals); joined on the current's stamps with the voltage
    averaged over each interval, R, Ke and J lie within their intervals."""
    half = _copy(chunked_bag, tmp_path / "half", lambda topic, k, raw: topic != "current" or k % 2)
    assert main(["check", str(half)]) == 0
    text = capsys.readouterr().out
    assert "recording: " in text and "'current' arrives every 2 ms" in text
    out = tmp_path / "r.json"
    assert main(["identify", str(half), "--quiet", "--no-holdout", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    spec = load_motor("seed000_ebike")
    p = spec.model.params
    truth = {"R": p.R, "Ke": p.Ke, "J": p.J * p.Ke / p.Kt}  # Kt = Ke closure
    for name, value in truth.items():
        est = doc["parameters"][name]
        lo, hi = est["ci95"]
        assert lo <= value <= hi, (name, est, value)
        assert abs(est["value"] / value - 1) < 0.005, (name, est["value"], value)
    assert doc["recording"][str(half)]["join"]


def test_samples_missing_on_one_topic_are_said_not_silently_dropped(chunked_bag, tmp_path):
    lossy = _copy(
        chunked_bag, tmp_path / "lossy", lambda topic, k, raw: topic != "encoder" or k % 97
    )
    run = bagio.read_bag(lossy)
    state = bagio.recording_state(lossy)
    assert state is not None and not state.complete
    dropped = sum(s.n for s in run.segments) // 97
    assert 0.9 * dropped <= state.missing_samples <= 1.1 * dropped + 1, state.missing_samples
    assert any("missing on some topic (encoder" in j for j in state.join)
    assert np.all(np.diff(np.concatenate([s.t for s in run.segments])) > 0)


def test_a_complete_bag_says_complete(chunked_bag, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(chunked_bag, out)
    bagio.read_bag(out)
    state = bagio.recording_state(out)
    assert state is not None and state.complete and not state.lines()
