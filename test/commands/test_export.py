"""``pmdc-ident export``: bag -> CSV and CSV -> bag, round trips through the command line."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.paths import FIXTURES
from helpers.plans import tiny_run

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.data import Run
from pmdc_ident.dataio.bagio import read_bag, write_bag
from pmdc_ident.dataio.csvio import read_csv, write_csv


@pytest.fixture(scope="module")
def run() -> Run:
    return tiny_run(seed=5)


def _same(a: Run, b: Run, t_atol: float) -> None:
    assert a.labels == b.labels
    for sa, sb in zip(a.segments, b.segments, strict=True):
        np.testing.assert_allclose(sb.t, sa.t, rtol=0, atol=t_atol)
        for name in ("voltage", "current", "position", "speed", "terminal_voltage"):
            x, y = getattr(sa, name), getattr(sb, name)
            assert (x is None) == (y is None), name
            if x is not None:
                np.testing.assert_array_equal(y, x)  # NaN (open armature) where x has NaN


def test_bag_to_csv_holds_exactly_what_read_bag_gives(run, tmp_path, capsys):
    bag = write_bag(run, tmp_path / "bag")
    out = tmp_path / "run.csv"
    assert main(["export", str(bag), "--csv", str(out)]) == 0
    n = sum(s.n for s in run.segments)
    assert f"{len(run.segments)} segment(s), {n} samples" in capsys.readouterr().out
    _same(read_bag(bag), read_csv(out), t_atol=0.0)
    # the coast-down's open armature is an empty voltage cell
    text = out.read_text().splitlines()
    coast_rows = [r for r in text if r.endswith(",coast")]
    assert sum(1 for r in coast_rows if r.split(",")[1] == "") == run.segments[-1].open_mask.sum()


def test_csv_to_bag_and_back_round_trips(run, tmp_path):
    first = write_csv(run, tmp_path / "in.csv")
    bag = tmp_path / "bag"
    assert main(["export", str(first), "--bag", str(bag)]) == 0
    assert (bag / "metadata.yaml").is_file()
    back = tmp_path / "back.csv"
    assert main(["export", str(bag), "--csv", str(back)]) == 0
    # values exact; times through integer nanosecond stamps (1 ns)
    _same(read_csv(first), read_csv(back), t_atol=1e-9)


def test_the_papers_real_staircase_table_round_trips_through_a_bag(tmp_path):
    src = FIXTURES / "seed000_table4.csv"
    bag = tmp_path / "table4"
    assert main(["export", str(src), "--bag", str(bag)]) == 0
    back = tmp_path / "table4.csv"
    assert main(["export", str(bag), "--csv", str(back)]) == 0
    _same(read_csv(src), read_csv(back), t_atol=1e-9)


def test_bad_input_is_one_clear_line_and_an_exit_status(run, tmp_path, capsys):
    assert main(["export", str(tmp_path / "missing.csv"), "--bag", str(tmp_path / "b")]) == (
        EXIT_USER_ERROR
    )
    err = capsys.readouterr().err.strip()
    assert err.startswith("pmdc-ident export: error:") and "\n" not in err
    bag = write_bag(run, tmp_path / "exists")
    csv = write_csv(run, tmp_path / "r.csv")
    assert main(["export", str(csv), "--bag", str(bag)]) == EXIT_USER_ERROR
    err = capsys.readouterr().err.strip()
    assert "never overwritten" in err and "\n" not in err
    assert main(["export", str(csv), "--csv", str(tmp_path / "x.csv"), "--session", "a"]) == (
        EXIT_USER_ERROR
    )
