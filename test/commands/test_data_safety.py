"""No write destroys an input or leaves a partial file under a final name (issue 28, item 1).

Each case was found by a user: a batch written over its own recordings, a report
folder holding the input, a motor file written onto a sidecar, a full disk leaving
truncated CSVs and 0-byte YAML, an interrupted batch truncating the previous run's
reports. In-process and fast; the signal cases with real processes are in
``test_process_lifetimes.py``.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest
from helpers.full_disk import files_in, nearly_full
from helpers.paths import FIXTURES

from pmdc_ident.cli import EXIT_INTERRUPTED, EXIT_USER_ERROR, main
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio.csvio import read_csv, write_csv

TABLE = FIXTURES / "seed000_table4.csv"


def _tree(folder: Path) -> dict[str, bytes]:
    files = [p for p in sorted(folder.rglob("*")) if p.is_file()]
    return {str(p.relative_to(folder)): p.read_bytes() for p in files}


def _one_error(capsys, argv: list[str], *match: str) -> str:
    rc = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == EXIT_USER_ERROR, err
    assert len(lines) == 1, err
    for m in match:
        assert m in lines[0], err
    return lines[0]


@pytest.fixture(scope="module")
def session_csv(tmp_path_factory) -> Path:
    """A short seed-001 session (about 60 kB of CSV): a fit in about a second."""
    spec = load_motor("seed001_110v")
    cfg = SequenceConfig(
        staircase_levels=3, staircase_hold_tau=3.0, step_hold_tau=3.0, sweep_duration_tau=10.0
    )
    run = synthesize_run(spec.model, plan_for_motor(spec, 2e-3, cfg), spec.sensors, seed=3)
    return write_csv(run, tmp_path_factory.mktemp("session") / "run.csv")


def test_batch_into_the_input_folder_never_writes_over_a_txt_recording(tmp_path, capsys):
    logs = tmp_path / "logs"
    logs.mkdir()
    shutil.copy(TABLE, logs / "run.txt")  # .txt is an accepted CSV suffix
    before = _tree(logs)
    _one_error(
        capsys, ["identify", "--batch", str(logs), str(logs)], "run.txt", "that is the input"
    )
    assert _tree(logs) == before


def test_diagnose_batch_with_a_glob_is_refused_the_same_way(tmp_path, capsys):
    shutil.copy(TABLE, tmp_path / "a.txt")
    before = _tree(tmp_path)
    _one_error(capsys, ["diagnose", "--batch", str(tmp_path), str(tmp_path / "*.txt")], "a.txt")
    assert _tree(tmp_path) == before


def test_monitor_report_never_replaces_the_input_it_replays(tmp_path, capsys):
    x = tmp_path / "X"
    x.mkdir()
    shutil.copy(TABLE, x / "drift.csv")  # the name the report would write
    before = _tree(x)
    argv = ["monitor", str(x / "drift.csv"), "--params", "seed000_ebike", "--report", str(x)]
    _one_error(capsys, argv, "drift.csv", "that is the input")
    assert _tree(x) == before


@pytest.mark.parametrize("exists", [True, False], ids=["sidecar present", "sidecar name free"])
def test_a_motor_file_is_never_written_onto_a_sidecar_name(tmp_path, capsys, exists):
    run = tmp_path / "run.csv"
    shutil.copy(TABLE, run)
    if exists:
        (tmp_path / "run.csv.yaml").write_text("current_unit: A\n")
    before = _tree(tmp_path)
    argv = ["identify", str(run), "--yaml", str(run) + ".yaml", "--quiet"]
    _one_error(capsys, argv, "sidecar name of the input")
    assert _tree(tmp_path) == before


def test_the_writer_itself_refuses_what_the_command_read(tmp_path):
    """The net under the up-front check: inside a command, a write onto anything a
    reader registered is refused, whatever spelling leads to it."""
    from pmdc_ident.core import safe_write

    run = tmp_path / "run.csv"
    shutil.copy(TABLE, run)
    (tmp_path / "link.csv").symlink_to(run)
    with safe_write.reading_scope():
        read_csv(run)
        for target in (run, tmp_path / "link.csv", tmp_path / "." / "run.csv"):
            with pytest.raises(safe_write.WriteRefusedError, match="the input"):
                safe_write.write_text(target, "x")
    assert run.read_bytes() == TABLE.read_bytes()
    safe_write.write_text(tmp_path / "other.csv", "x")  # outside a scope: a library call
    assert not list(tmp_path.glob(".*partial*"))


def test_write_is_atomic_and_keeps_the_mode_of_the_file_it_replaces(tmp_path):
    from pmdc_ident.core import safe_write

    target = tmp_path / "out.json"
    target.write_text("old")
    target.chmod(0o640)
    with pytest.raises(RuntimeError), safe_write.atomic_open(target) as fh:
        fh.write("half")
        raise RuntimeError
    assert target.read_text() == "old"
    safe_write.write_text(target, "new")
    assert target.read_text() == "new"
    assert target.stat().st_mode & 0o777 == 0o640
    assert [p.name for p in tmp_path.iterdir()] == ["out.json"]


def test_a_dead_process_temporary_is_swept_by_the_next_write(tmp_path):
    from pmdc_ident.core import safe_write

    stale = tmp_path / ".out.csv.999999999.0123abcd.partial"
    stale.write_text("from a process killed with -9")
    safe_write.write_text(tmp_path / "out.csv", "whole")
    assert not stale.exists()


def test_a_link_is_followed_only_to_a_file_of_its_kind_or_a_special_file(tmp_path, capsys):
    """``out.yaml`` linked to a recording is refused; ``out.json`` linked to ``/dev/null``
    or a named pipe (which have no suffix and nothing to replace) is written through."""
    import os
    import threading

    from pmdc_ident.core import safe_write

    run = tmp_path / "run.csv"
    shutil.copy(TABLE, run)
    (tmp_path / "out.yaml").symlink_to(run)
    with pytest.raises(safe_write.WriteRefusedError, match="a link to"):
        safe_write.write_text(tmp_path / "out.yaml", "x")
    assert run.read_bytes() == TABLE.read_bytes()

    (tmp_path / "null.json").symlink_to(os.devnull)
    safe_write.write_text(tmp_path / "null.json", "{}")
    assert (tmp_path / "null.json").is_symlink()
    assert main(["check", str(run), "--json", str(tmp_path / "null.json")]) == 0, (
        capsys.readouterr().err
    )

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    (tmp_path / "pipe.json").symlink_to(fifo)
    got: list[str] = []
    reader = threading.Thread(target=lambda: got.append(fifo.read_text()))
    reader.start()
    safe_write.write_text(tmp_path / "pipe.json", "through")
    reader.join(5)
    assert got == ["through"]
    assert not list(tmp_path.glob(".*partial*"))


def test_plan_writes_through_the_one_writer(tmp_path, capsys):
    """``plan`` (issue 25) had its own temp-file-and-rename: the plan replaced a symlink
    by a file, left a replaced file readable by its owner only (0600), and a temporary
    that a ``kill -9`` left stayed for good. Now it keeps the link and the mode and sweeps
    a dead process's temporary, as every other output does."""
    real = tmp_path / "plans" / "plan.csv"
    real.parent.mkdir()
    real.write_text("an older plan\n")
    real.chmod(0o644)
    link = tmp_path / "plan.csv"
    link.symlink_to(real)
    stale = real.parent / ".plan.csv.999999999.0123abcd.partial"
    stale.write_text("from a plan killed with -9")
    pre = tmp_path / "pre.csv"
    pre.write_text("an older pre-test\n")
    pre.chmod(0o640)
    assert main(["plan", "seed001_110v", "--csv", str(link)]) in (0, 3), capsys.readouterr().err
    assert main(["plan", "seed001_110v", "--pretest", str(pre)]) == 0, capsys.readouterr().err
    assert link.is_symlink() and real.read_text().startswith("#")
    assert real.stat().st_mode & 0o777 == 0o644
    assert pre.stat().st_mode & 0o777 == 0o640 and "segment" in pre.read_text()
    assert not stale.exists()
    assert sorted(p.name for p in real.parent.iterdir()) == ["plan.csv"]


# ---------------------------------------------------------------------------
# A full disk: the previous file stays, no partial file under any final name
# ---------------------------------------------------------------------------
FULL_CASES = {
    "export --csv": (["export", "{run}", "--csv", "{out}/out.csv"], "out.csv"),
    "identify --json": (["identify", "{run}", "--quiet", "--json", "{out}/r.json"], "r.json"),
    "identify --yaml": (["identify", "{run}", "--quiet", "--yaml", "{out}/m.yaml"], "m.yaml"),
    "identify --report": (
        ["identify", "{run}", "--quiet", "--no-holdout", "--report", "{out}/rep"],
        "rep/identify.json",
    ),
    "export --bag": (["export", "{run}", "--bag", "{out}/bag"], None),
    "plan --csv": (["plan", "seed001_110v", "--csv", "{out}/plan.csv"], "plan.csv"),
    "plan --pretest": (["plan", "seed001_110v", "--pretest", "{out}/pre.csv"], "pre.csv"),
}


@pytest.mark.parametrize("case", list(FULL_CASES), ids=list(FULL_CASES))
def test_full_disk_leaves_the_previous_file_and_no_partial_one(
    case, session_csv, tmp_path, capsys
):
    argv_t, previous = FULL_CASES[case]
    out = tmp_path / "disk"
    keep = {}
    if previous is not None and "/" not in previous:
        keep[previous] = b"the previous, complete result\n"
    with nearly_full(out, leave_bytes=0, keep=keep):
        argv = [a.format(run=session_csv, out=out) for a in argv_t]
        before = files_in(out)
        rc = main(argv)
        err = capsys.readouterr().err
        after = files_in(out)
    assert rc == EXIT_USER_ERROR, err
    assert "No space left on device" in err.strip().splitlines()[-1], err
    assert "Traceback" not in err
    # what was there is there, unchanged; nothing else (a report folder may be new, empty)
    assert after == before, sorted(after)


# ---------------------------------------------------------------------------
# Batches: an interrupted re-run truncates nothing; a failed input leaves no stale JSON
# ---------------------------------------------------------------------------
def test_an_interrupted_batch_rerun_keeps_the_previous_complete_results(
    session_csv, tmp_path, capsys, monkeypatch
):
    data = tmp_path / "in"
    data.mkdir()
    shutil.copy(session_csv, data / "a.csv")
    shutil.copy(session_csv, data / "b.csv")
    out = tmp_path / "out"
    argv = ["identify", str(data), "--batch", str(out), "--jobs", "1", "--no-holdout"]
    assert main(argv) == 0
    capsys.readouterr()
    before = _tree(out)
    assert all(before.values())

    import pmdc_ident.app.inputs as inputs

    real = inputs.prepare_inputs
    calls = []

    def interrupted(*a, **k):
        calls.append(1)
        if len(calls) == 2:  # the second input: Ctrl-C in the middle of it
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(inputs, "prepare_inputs", interrupted)
    import pmdc_ident.app.service as service

    monkeypatch.setattr(service, "prepare_inputs", interrupted)
    assert main(argv) == EXIT_INTERRUPTED
    capsys.readouterr()
    after = _tree(out)
    assert after["b.json"] == before["b.json"] and after["b.txt"] == before["b.txt"]
    assert all(after.values()), "a result truncated"
    assert not list(out.glob(".*partial*"))


def test_a_failed_input_leaves_no_result_of_an_older_run(session_csv, tmp_path, capsys):
    data = tmp_path / "in"
    data.mkdir()
    shutil.copy(session_csv, data / "a.csv")
    out = tmp_path / "out"
    argv = ["identify", str(data), "--batch", str(out), "--jobs", "1", "--no-holdout"]
    assert main(argv) == 0
    assert json.loads((out / "a.json").read_text())["parameters"]
    (data / "a.csv").write_text("t,voltage,speed\n0,1,0\n0.001,1,1\n")  # now unusable
    assert main(argv) == 2
    capsys.readouterr()
    assert not (out / "a.json").exists()
    assert "FAILED" in (out / "a.txt").read_text()
