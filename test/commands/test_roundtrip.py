"""pmdc-ident roundtrip: a run with a withheld effect, diagnosed, exported, replayed in MuJoCo."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pmdc_ident.benchmark.mujoco_cases import make_mj_case, record_mj
from pmdc_ident.benchmark.runner import write_recording
from pmdc_ident.cli import main
from pmdc_ident.exports import roundtrip as roundtrip_mod

mujoco = pytest.importorskip("mujoco")


def _run(tmp_path, name: str, equation: str, level: int, seed: int):  # type: ignore[no-untyped-def]
    """A short run of MuJoCo's plant (an equation nobody here wrote) with one effect."""
    case = make_mj_case(
        name, "effect", (name,), np.random.default_rng(seed), level=level, equation=equation,
        max_samples=2500,
    )  # fmt: skip
    rec, _ = record_mj(case, with_visibility=False)
    return write_recording(rec, tmp_path / f"{name}.csv")


@pytest.mark.parametrize(
    ("name", "equation", "level", "seed"),
    [
        ("coulomb_friction", "frictionloss", 3, 51),
        ("quadratic_drag", "quadratic", 3, 53),
        ("delay", "transport", 2, 57),
    ],
)
def test_the_shrink_in_mujoco_is_the_project_s_within_5_points(
    tmp_path, capsys, monkeypatch, name, equation, level, seed
):
    data = _run(tmp_path, name, equation, level, seed)
    out = tmp_path / "rt.json"
    # what chooses the export (the heating's thermal reference) sees the fit segments only
    seen: list[str] = []
    real = roundtrip_mod.thermal_reference

    def spy(*args, **kwargs):  # type: ignore[no-untyped-def]
        for a in (*args, *kwargs.values()):  # every segment it is handed, whatever the slot
            if isinstance(a, list | tuple):
                seen.extend(s.label for s in a if hasattr(s, "label"))
        return real(*args, **kwargs)

    monkeypatch.setattr(roundtrip_mod, "thermal_reference", spy)
    rc = main(["roundtrip", str(data), "--quiet", "--json", str(out), "--mujoco-dir",
               str(tmp_path / "mjcf")])  # fmt: skip
    text = capsys.readouterr().out
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["effects"] == [name] and doc["carried"] == [name]
    assert seen and not set(seen) & set(doc["held_out"]), (seen, doc["held_out"])
    assert doc["project"]["shrink"] > 0.8
    assert abs(doc["difference_points"]) <= 5.0
    # the plain export in MuJoCo misses by what the project's plain model misses
    assert doc["mujoco"]["gap_plain"] == pytest.approx(doc["project"]["gap_plain"], rel=0.05)
    assert "MuJoCo replay" in text and "points" in text
    for f in ("plain.mjcf.xml", "diagnosed.mjcf.xml"):
        mujoco.MjModel.from_xml_path(str(tmp_path / "mjcf" / f))


def test_an_effect_mujoco_cannot_carry_shrinks_nothing_there_and_says_why(tmp_path, capsys):
    data = _run(tmp_path, "brush_drop", "tanh", 3, 61)
    out = tmp_path / "rt.json"
    assert main(["roundtrip", str(data), "--quiet", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["effects"] == ["brush_drop"] and doc["carried"] == []
    assert doc["mujoco"]["shrink"] < 0.05 < doc["project"]["shrink"]
    assert any(line.startswith("brush_drop:") for line in doc["not_carried"])
    assert "not carried: brush_drop" in capsys.readouterr().out


def test_bad_options_are_one_line(tmp_path, capsys):
    data = _run(tmp_path, "coulomb_friction", "frictionloss", 3, 51)
    assert main(["roundtrip", str(data), "--substeps", "0"]) == 2
    assert main(["roundtrip", str(data), "--json", str(tmp_path / "x.txt")]) == 2
    assert main(["roundtrip", str(data), "--json", str(data)]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "--substeps" in err
