"""A bag its recorder never closed: every complete chunk is read, the loss said in one line.

The recorder is killed for real in test_identification_node.py; here a written bag
is cut at many byte offsets (every byte of its head, around every chunk boundary,
and at random places), as a killed writer or a cut copy leaves it.
"""

from __future__ import annotations

import logging
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from pmdc_ident.core.data import Run
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio import bagio
from pmdc_ident.dataio.bagio import BagWriter, read_bag, read_driver_arrays, write_bag
from pmdc_ident.dataio.mcap_recover import scan_mcap

SHORT = SequenceConfig(
    staircase_levels=2, staircase_hold_tau=4.0, step_hold_tau=4.0, sweep_duration_tau=10.0
)


class _WriteClock:
    """bagio's clock while the fixture writes: 1 ms per call, so a chunk every ~150 writes."""

    def __init__(self) -> None:
        self.t = 0.0

    def monotonic(self) -> float:
        self.t += 1e-3
        return self.t


def _bag(path: Path, run: Run, flush_s: float) -> Path:
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(bagio, "time", _WriteClock())
        return write_bag(run, path, flush_s=flush_s)


@pytest.fixture(scope="module")
def session_run() -> Run:
    spec = load_motor("seed001_110v")
    return synthesize_run(spec.model, plan_for_motor(spec, 1e-3, SHORT), spec.sensors)


@pytest.fixture(scope="module")
def session_bag(tmp_path_factory, session_run) -> Path:
    """A simulated seed-001 session (10 s, 30 000 messages) in about 200 chunks."""
    return _bag(tmp_path_factory.mktemp("bag") / "session", session_run, 0.15)


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory, session_run) -> Path:
    """Its first two segments (1 s, 3000 messages) in about 60 chunks: cut many times."""
    run = Run(session_run.segments[:2], "first two segments")
    return _bag(tmp_path_factory.mktemp("bag") / "small", run, 0.02)


def _cut(src: Path, n: int, where: Path) -> Path:
    """A bag folder as a killed recorder leaves it: the first ``n`` bytes, no metadata."""
    if where.exists():
        shutil.rmtree(where)
    where.mkdir()
    (where / "cut.mcap").write_bytes(next(src.glob("*.mcap")).read_bytes()[:n])
    return where


def test_a_cut_bag_gives_its_complete_chunks_or_one_clear_error(small_bag, tmp_path, caplog):
    session_bag = small_bag
    full = scan_mcap(next(session_bag.glob("*.mcap")))
    assert full.complete and 30 < full.chunks < 200, full.chunks
    whole = read_driver_arrays(session_bag).encoder_ns
    ends = np.array([e for e, _ in full.chunk_ends])
    counts = np.array([m for _, m in full.chunk_ends])
    rng = np.random.default_rng(7)
    cuts = set(range(0, 300)) | set(rng.integers(0, full.size, 60).tolist())
    cuts |= {int(e) + d for e in ends for d in (-1, 0, 1)}
    read = failed = 0
    for n in sorted(cuts):
        bag = _cut(session_bag, n, tmp_path / "b")
        # the messages of the chunks that end at or before the cut, no more, no less
        k = int(np.searchsorted(ends, n, side="right"))
        if n >= 8:  # past the magic
            assert len(scan_mcap(bag / "cut.mcap").messages) == (counts[k - 1] if k else 0), n
        caplog.clear()
        try:
            with caplog.at_level(logging.WARNING, logger="pmdc_ident.bag"):
                arrays = read_driver_arrays(bag)
        except DataError as exc:  # never another exception, never a traceback
            assert str(exc).count("\n") == 0 and str(bag) in str(exc)
            failed += 1
            continue
        read += 1
        (line,) = [r.getMessage() for r in caplog.records]
        assert "truncated bag (its recorder did not close it)" in line or "none lost" in line
        enc = arrays.encoder_ns
        assert np.array_equal(enc, whole[: enc.size])  # a prefix of the session, in order
    assert read > 100 and failed > 100, (read, failed)
    # a cut anywhere in the summary after the data loses nothing
    bag = _cut(session_bag, full.size - 30, tmp_path / "b")
    assert np.array_equal(read_driver_arrays(bag).encoder_ns, whole)


def test_identify_and_export_read_a_cut_bag_and_say_what_was_lost(session_bag, tmp_path, capsys):
    ends = scan_mcap(next(session_bag.glob("*.mcap"))).chunk_ends
    size = ends[int(0.8 * len(ends))][0] + 10  # inside a chunk, 80 % into the session
    bag = _cut(session_bag, size, tmp_path / "killed")
    whole = read_bag(session_bag)
    part = read_bag(bag)
    assert 0 < len(part.segments) < len(whole.segments)  # the segment cut short is left out
    for seg in part.segments:
        assert seg.n == whole.segments[whole.labels.index(seg.label)].n
    for cmd in (
        ["export", str(bag), "--csv", str(tmp_path / "k.csv")],
        ["identify", str(bag), "--quiet", "--no-holdout", "--model", "linear"],  # the short fit
    ):
        out = subprocess.run(
            [sys.executable, "-m", "pmdc_ident.cli", *cmd],
            capture_output=True,
            text=True,
            timeout=300,
            check=False,
        )
        assert out.returncode == 0, out.stderr
        (line,) = out.stderr.strip().splitlines()  # what was lost, in one line
        assert "truncated bag" in line and f"lost its last 10 of {size} bytes" in line, line
    assert "Ke" in out.stdout and (tmp_path / "k.csv").stat().st_size > 0


def test_a_killed_writer_leaves_every_chunk_but_the_pending_one(tmp_path):
    """flush() hands each chunk to the file: what a SIGKILL right after it keeps."""
    w = BagWriter(tmp_path / "b", {"/encoder": "sensor_msgs/msg/JointState"}, flush_s=3600.0)
    w.open()
    from pmdc_ident.dataio.bagio import _joint_state

    for k in range(50):
        w.write_msg("/encoder", k, _joint_state(w.typestore, k * 10**6, ["s"], position=[k]))
        if k == 29:
            w.flush()
    mcap = next((tmp_path / "b").glob("*.mcap"))
    rec = scan_mcap(mcap)  # the file as it is on disk now, the writer still open
    assert [m[1] for m in rec.messages] == list(range(30)) and not rec.complete
    w.close()
    assert len(scan_mcap(mcap).messages) == 50


def test_a_segment_whose_samples_the_kill_cut_short_is_left_out(session_bag):
    """The recorder writes markers at once but holds samples: a killed recorder's bag may
    end a segment's samples before its end marker. That segment is left out, not read short."""
    from dataclasses import replace

    from pmdc_ident.dataio.bagio import assemble_run
    from pmdc_ident.dataio.mcap_recover import cut_markers

    arrays = read_driver_arrays(session_bag)
    whole = assemble_run(arrays)
    third = whole.segments[2]
    t0 = round(arrays.markers[0].t_s * 1e9)
    cut_ns = t0 + round(third.t[third.n // 2] * 1e9)  # samples end half-way through it
    c, e, v = (getattr(arrays, f"{t}_ns") <= cut_ns for t in ("current", "encoder", "voltage"))
    term = None if arrays.terminal_v is None else arrays.terminal_v[v]
    short = {
        "current_ns": arrays.current_ns[c],
        "current_a": arrays.current_a[c],
        "encoder_ns": arrays.encoder_ns[e],
        "position_rad": arrays.position_rad[e],
        "speed_rad_s": arrays.speed_rad_s[e],
        "voltage_ns": arrays.voltage_ns[v],
        "voltage_v": arrays.voltage_v[v],
        "terminal_v": term,
    }
    cut = replace(arrays, **short)
    assert [s.label for s in assemble_run(cut).segments][-1] == third.label  # read short
    markers, note = cut_markers(cut.markers, cut_ns, 1_000_000)
    part = assemble_run(replace(cut, markers=markers))
    assert [s.label for s in part.segments] == list(whole.labels[:2])
    assert [s.n for s in part.segments] == [s.n for s in whole.segments[:2]]
    assert "2 complete segment(s)" in note and f"'{third.label}' cut short and left out" in note
    assert f"end {third.t[third.n // 2]:.2f} s into session" in note


def _chunk_at(data: bytes, o: int) -> tuple[int, int]:
    """(start, end) of the first chunk record at or after byte ``o`` (a record start)."""
    while data[o] != 0x06:
        o += 9 + int.from_bytes(data[o + 1 : o + 9], "little")
    return o, o + 9 + int.from_bytes(data[o + 1 : o + 9], "little")


def test_a_damaged_chunk_ends_reading_there_and_is_told_apart_from_a_cut(small_bag, tmp_path):
    """A chunk that fits in the file but does not parse is damage (said, with its byte);
    a chunk the end of the file cuts short is a cut (no damage). Either way every chunk
    before it is read and none of its own messages."""
    mcap = next(small_bag.glob("*.mcap"))
    full, data = scan_mcap(mcap), mcap.read_bytes()
    end4, n4 = full.chunk_ends[4]
    start, end = _chunk_at(data, end4)
    damaged = bytearray(data[: full.chunk_ends[8][0]])
    damaged[start + 9 : end] = b"\xff" * (end - start - 9)  # framing kept, content garbage
    (tmp_path / "damaged.mcap").write_bytes(bytes(damaged))
    rec = scan_mcap(tmp_path / "damaged.mcap")
    assert len(rec.messages) == n4 and rec.chunks == 5 and rec.good_end == start
    assert rec.damage.startswith(f"damaged record at byte {start}:"), rec.damage
    assert "damaged record" in rec.line()
    (tmp_path / "cut.mcap").write_bytes(data[: end - 1])
    cut = scan_mcap(tmp_path / "cut.mcap")
    assert len(cut.messages) == n4 and cut.good_end == start and cut.damage == ""
