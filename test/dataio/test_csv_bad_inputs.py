"""CSV files as other tools and mistakes make them: one line naming the file's line, exit 2.

Each case goes through ``identify``, ``diagnose`` and ``export`` in-process; a
refused file is refused before any fit, so the whole file runs in seconds.
"""

from __future__ import annotations

import pytest

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.dataio.csvio import read_csv

HEAD = "t,voltage,current,speed,segment\n"


def _rows(n: int = 6, t0: float = 0.0, label: str = "step", scale: float = 1.0) -> str:
    cells = ((t0 + 0.01 * k, 2.0, 0.5, float(k)) for k in range(n))
    return "".join(",".join(repr(c * scale) for c in row) + f",{label}\n" for row in cells)


COMMENTS = "# logged by a bench PC\n# second note\n\n"

BAD_CSV: dict[str, tuple[str | bytes, str]] = {
    "bad cell after comment lines names the file line": (
        COMMENTS + HEAD + "0,1,0.5,0,a\n0.01,x,0.5,1,a\n",
        "line 6: 'voltage' is not a number",
    ),
    "extra cells on a row": (HEAD + _rows(3) + "0.03,2,0.5,3,step,7.5\n", "line 5: 6 cells"),
    "a cut-off row": (HEAD + _rows(3) + "0.03,2\n", "line 5: 2 cells, the header has 5"),
    "cut off inside the header": ("t,volt", "needs a 'position' or 'speed' column"),
    "time back at a segment boundary": (
        HEAD + _rows(4, label="a") + _rows(4, label="b"),
        "line 6: time does not increase",
    ),
    "time repeated at a segment boundary": (
        HEAD + _rows(3, label="a") + "0.02,2,0.5,9,b\n0.03,2,0.5,9,b\n",
        "line 5: time does not increase",
    ),
    "every value times 1e300": (HEAD + _rows(scale=1e300), "beyond any motor test"),
    "time times 1e-300": (
        "t,voltage,current,speed\n" + "".join(f"{k * 1e-300!r},2,0.5,{k}\n" for k in range(5)),
        "is t in seconds?",
    ),
    "epoch nanoseconds as t": (
        "t,voltage,current,speed\n"
        + "".join(f"{1.7e18 + k * 1e6!r},2,0.5,{k}\n" for k in range(5)),
        "t = 1.7e+18 s",
    ),
    "speed in the 1e300s": (
        "t,voltage,current,speed\n0,1,0,0\n0.01,1,0,1e300\n0.02,1,0,0\n",
        "speed = 1e+300 rad/s",
    ),
    "current of 1e9 A": ("t,voltage,current,speed\n0,1,1e9,0\n0.01,1,0,1\n", "current = 1e+09"),
    "negative 1e300 voltage": (
        "t,voltage,current,speed\n0,-1e300,0,0\n0.01,1,0,1\n",
        "voltage = -1e+300",
    ),
    "semicolon-separated (European spreadsheet)": (
        "t;voltage;current;speed\n0;1;0;0\n",
        "separated by commas",
    ),
    "tab-separated": ("t\tvoltage\tcurrent\tspeed\n0\t1\t0\t0\n", "tabs"),
    "decimal commas": ("t,voltage,current,speed\n0,1,5,0,2,0\n", "6 cells, the header has 4"),
    "UTF-16 with a byte-order mark": (
        "t,voltage,current,speed\n0,1,0,0\n".encode("utf-16"),
        "not a text (UTF-8)",
    ),
    "UTF-16 without a byte-order mark": (
        "t,voltage,current,speed\n0,1,0,0\n".encode("utf-16-le"),
        "NUL bytes",
    ),
    "an unterminated quote": (
        'T,Voltage,Current,Speed\n0,"1,0,0\n0.01,1,0,1\n',
        "line 2: 2 cells",
    ),
    "a cell longer than any number": (
        "t,voltage,current,speed\n0,1,0," + "9" * 200_000 + "\n",
        "line 2",
    ),
    "a header repeated mid-file (files concatenated)": (
        HEAD + _rows(3) + HEAD + _rows(3, t0=1.0),
        "line 5: 't' is not a number",
    ),
    "inf time": ("t,voltage,current,speed\n0,1,0,0\ninf,1,0,1\n", "line 3: 't' is 'inf'"),
    "empty time cell": ("t,voltage,current,speed\n0,1,0,0\n,1,0,1\n", "empty 't' cell"),
    "only comments": (COMMENTS, "empty file"),
    "a header and comments only": (COMMENTS + HEAD + "# no data yet\n", "header only"),
}


def _write(tmp_path, content: str | bytes):
    p = tmp_path / "run.csv"
    if isinstance(content, bytes):
        p.write_bytes(content)
    else:
        p.write_text(content)
    return p


@pytest.mark.parametrize("case", sorted(BAD_CSV))
@pytest.mark.parametrize("command", ["identify", "diagnose", "export"])
def test_bad_csv_is_one_line_naming_the_problem_and_exit_2(case, command, tmp_path, capsys):
    content, match = BAD_CSV[case]
    p = _write(tmp_path, content)
    argv = [command, str(p), "--quiet"]
    if command == "export":
        argv = [command, str(p), "--bag", str(tmp_path / "bag")]
    rc = main(argv)
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert rc == EXIT_USER_ERROR, (out, err)
    assert len(lines) == 1 and lines[0].startswith(f"pmdc-ident {command}: error:"), err
    assert match in lines[0], err
    assert "Warning" not in err and "Traceback" not in err
    assert not (tmp_path / "bag").exists()


def test_trailing_separator_and_crlf_and_bom_are_read(tmp_path):
    text = "\ufeff" + (HEAD.strip() + ",\r\n") + _rows(4).replace("\n", ",\r\n")
    run = read_csv(_write(tmp_path, text))
    assert run.labels == ("step",) and run.segments[0].n == 4


def test_time_over_segments_that_increases_is_read(tmp_path):
    run = read_csv(_write(tmp_path, HEAD + _rows(3, label="a") + _rows(3, t0=0.03, label="b")))
    assert run.labels == ("a", "b")
    assert run.segments[1].history_voltage is not None  # read as a continuation
