"""Bad options and output paths: one clear line, exit 2, nothing written, never a traceback.

Every case here was found by trying the command as a demanding user would
(issue 10). Each runs in-process and fails before any fit, so the file is fast.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest
from helpers.paths import FIXTURES

from pmdc_ident.cli import EXIT_INTERNAL_ERROR, EXIT_INTERRUPTED, EXIT_USER_ERROR, main
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio.bagio import write_bag
from pmdc_ident.dataio.csvio import read_csv

FIX = FIXTURES
TABLE = FIX / "seed000_table4.csv"
MOTOR = "parameters: {R: 1.0, L: 1.0e-3, Ke: 0.1, Kt: 0.1, J: 1.0e-3, B: 1.0e-4}\n"


@pytest.fixture()
def work(tmp_path, monkeypatch) -> Path:
    """A scratch folder as the current directory, holding a CSV, a bag and a plain file."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(TABLE, tmp_path / "run.csv")
    write_bag(read_csv(TABLE), tmp_path / "bag", session="s1")
    (tmp_path / "f").write_text("")
    return tmp_path


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): (b"" if p.is_dir() else p.read_bytes())
        for p in sorted(folder.rglob("*"))
    }


def one_error(capsys, argv: list[str], match: str) -> str:
    """``argv`` fails with exit 2 and exactly one stderr line containing ``match``."""
    rc = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == EXIT_USER_ERROR, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"pmdc-ident {argv[0]}: error:"), err
    assert match in lines[0], err
    return lines[0]


ARGS_BAD = {
    # output paths: refused before any work, nothing written
    "identify --report onto a file": (["identify", "run.csv", "--report", "f"], "not a folder"),
    "diagnose --report onto a file": (["diagnose", "run.csv", "--report", "f"], "not a folder"),
    "--report into a missing folder": (
        ["identify", "run.csv", "--report", "nodir/rep"],
        "folder nodir does not exist",
    ),
    "--report into the input bag": (["identify", "bag", "--report", "bag"], "input"),
    "--json into a missing folder": (
        ["identify", "run.csv", "--json", "/nonexistent/dir/o.json"],
        "folder /nonexistent/dir does not exist",
    ),
    "diagnose --json into a missing folder": (
        ["diagnose", "run.csv", "--json", "nodir/o.json"],
        "folder nodir does not exist",
    ),
    "--json onto the input": (["identify", "run.csv", "--json", "run.csv"], ".json"),
    "--json inside the input bag": (["identify", "bag", "--json", "bag/r.json"], "input folder"),
    "--json names a folder": (["identify", "run.csv", "--json", "bag"], "is a folder"),
    "--yaml with a wrong suffix": (["identify", "run.csv", "--yaml", "m.txt"], ".yaml"),
    "--json and --yaml both stdout": (
        ["identify", "run.csv", "--json", "-", "--yaml", "-"],
        "both write to standard output",
    ),
    "--report -": (["identify", "run.csv", "--report", "-"], "standard output"),
    "export --csv out.txt": (["export", "bag", "--csv", "out.txt"], "must end in .csv"),
    "export --bag out.csv": (["export", "run.csv", "--bag", "out.csv"], "not a .csv file"),
    "export --bag onto a file": (["export", "run.csv", "--bag", "f"], "not a folder"),
    "export --bag onto a bag": (["export", "run.csv", "--bag", "bag"], "never overwritten"),
    "export --csv onto the input": (
        ["export", "run.csv", "--csv", "./run.csv"],
        "refusing to write over an input",
    ),
    "export --csv inside the input bag": (["export", "bag", "--csv", "bag/x.csv"], "input"),
    "export --csv into a missing folder": (
        ["export", "bag", "--csv", "/nonexistent/x.csv"],
        "does not exist",
    ),
    "export --bag -": (["export", "run.csv", "--bag", "-"], "standard output"),
    "export --session unknown": (
        ["export", "bag", "--csv", "s.csv", "--session", "nosuch"],
        "no session 'nosuch' (sessions in it: s1)",
    ),
    "the same DATA twice": (["identify", "run.csv", "./run.csv"], "given twice"),
    "diagnose: the same bag twice": (["diagnose", "bag", "bag/"], "given twice"),
    "identify --batch into a missing folder": (
        ["identify", "--batch", "/nonexistent/out", "run.csv"],
        "folder /nonexistent does not exist",
    ),
    "diagnose --batch onto a file": (["diagnose", "--batch", "f", "run.csv"], "not a folder"),
    "identify --batch into the input bag": (["identify", "--batch", "bag", "bag"], "input"),
    "benchmark --json into a missing folder (before the long run)": (
        ["benchmark", "--json", "nodir/b.json"],
        "folder nodir does not exist",
    ),
    "benchmark --keep onto a file": (["benchmark", "--keep", "f"], "not a folder"),
    # parameters given by the user
    "--fix conflicting repeats": (
        ["identify", "run.csv", "--fix", "R=1", "--fix", "R=2"],
        "given twice with different values",
    ),
    "--fix negative friction": (
        ["identify", "run.csv", "--fix", "coulomb_friction.torque_nm=-0.01"],
        "outside the range of the Coulomb friction torque",
    ),
    "--fix R=1e300": (["identify", "run.csv", "--fix", "R=1e300"], "physical range"),
    "--fix J=1e-30": (["identify", "run.csv", "--fix", "J=1e-30"], "physical range"),
    "--fix unknown name (case)": (["identify", "run.csv", "--fix", "r=1"], "unknown parameter"),
    "diagnose --fix an effect": (
        ["diagnose", "run.csv", "--fix", "load_torque.torque_nm=0.1"],
        "unknown parameter",
    ),
    "--closure none without a scale": (
        ["identify", "run.csv", "--closure", "none"],
        "--fix Kt=..., --fix J=... or --added-inertia",
    ),
    "diagnose --max-effects 0": (["diagnose", "run.csv", "--max-effects", "0"], "--max-effects"),
    "virtual-board --seed -1": (["virtual-board", "--seed", "-1"], "--seed"),
    "virtual-board --link onto a file": (["virtual-board", "--link", "f"], "only replaces a sym"),
    "virtual-board --link onto a folder": (["virtual-board", "--link", "bag"], "a folder exists"),
    "virtual-board --link into a missing folder": (
        ["virtual-board", "--link", "nodir/port"],
        "folder nodir does not exist",
    ),
    "virtual-board --motor a binary": (["virtual-board", "--motor", "bin.yaml"], "not UTF-8"),
    "virtual-board --motor a CSV": (["virtual-board", "--motor", "run.csv"], "'parameters'"),
    "virtual-board --motor R=1e300": (["virtual-board", "--motor", "big.yaml"], "physical range"),
}


@pytest.mark.parametrize("case", sorted(ARGS_BAD))
def test_bad_option_is_one_line_exit_2_and_writes_nothing(case, work, capsys):
    argv, match = ARGS_BAD[case]
    (work / "bin.yaml").write_bytes(bytes(range(256)) * 4)
    (work / "big.yaml").write_text(MOTOR.replace("R: 1.0", "R: 1.0e300"))
    before = _snapshot(work)
    line = one_error(capsys, argv, match)
    assert "Warning" not in line and "Traceback" not in line
    assert _snapshot(work) == before
    assert not Path("/nonexistent").exists()


def test_json_and_yaml_dash_mean_stdout_and_keep_stdout_parseable(work, capsys):
    assert main(["identify", "run.csv", "--json", "-", "--quiet"]) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)  # only the document on stdout; the table went to stderr
    assert doc["parameters"]["Ke"]["identifiable"] is True
    assert "95 % interval" in err
    assert not (work / "-").exists()
    assert main(["identify", "run.csv", "--yaml", "-", "--quiet"]) == 0
    (work / "m.yaml").write_text(capsys.readouterr().out)
    assert load_motor(work / "m.yaml").model.params.Ke == pytest.approx(
        doc["parameters"]["Ke"]["value"]
    )


def test_export_csv_dash_writes_the_run_to_stdout(work, capsys):
    assert main(["export", "bag", "--csv", "-"]) == 0
    out, err = capsys.readouterr()
    (work / "back.csv").write_text(out)
    assert read_csv(work / "back.csv").labels == read_csv(TABLE).labels
    assert "12 segment(s)" in err and not (work / "-").exists()


def test_repeating_the_same_fix_is_harmless(work, capsys):
    assert main(["identify", "run.csv", "--fix", "R=1.2", "--fix", "R=1.2", "--quiet"]) == 0
    assert "R fixed at 1.2" in capsys.readouterr().out


def test_write_error_is_one_line(work, capsys):
    os.symlink("/dev/full", work / "full.json")  # every write fails: no space left
    one_error(capsys, ["identify", "run.csv", "--json", "full.json", "--quiet"], "No space")


@pytest.mark.parametrize(
    "exc",
    [KeyboardInterrupt(), SystemError("returned a result with an exception set")],
    ids=["KeyboardInterrupt", "SystemError from a compiled kernel"],
)
def test_ctrl_c_anywhere_in_a_command_is_one_line_and_130(exc, work, capsys, monkeypatch):
    import pmdc_ident.app.inputs as cmd  # identify reads its DATA there (the service)

    def interrupted(*_a, **_k):
        if isinstance(exc, SystemError):
            # as numba reports a Ctrl-C that lands while its kernel calls back into Python
            raise exc from KeyboardInterrupt()
        raise exc

    monkeypatch.setattr(cmd, "load_inputs", interrupted)
    assert main(["identify", "run.csv"]) == EXIT_INTERRUPTED
    assert capsys.readouterr().err == "pmdc-ident identify: interrupted\n"


def test_a_bug_of_ours_is_one_line_exit_1_and_debug_shows_the_traceback(work, capsys, monkeypatch):
    import pmdc_ident.app.inputs as cmd  # identify reads its DATA there (the service)

    def broken(*_a, **_k):
        raise RuntimeError("boom\nsecond line")

    monkeypatch.setattr(cmd, "load_inputs", broken)
    assert main(["identify", "run.csv"]) == EXIT_INTERNAL_ERROR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error: RuntimeError: boom" in err
    monkeypatch.setenv("PMDC_IDENT_DEBUG", "1")
    with pytest.raises(RuntimeError):
        main(["identify", "run.csv"])
