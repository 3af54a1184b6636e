"""Second looks: the split with its sides swapped (two-fold cross-validation), the
backward step of the combination search, and the signal chain's lag on top of an
effect when the lag alone helped only as a chain lag.

The records come from the independent benchmark generator (its own plant and effect
equations, :mod:`pmdc_ident.benchmark`), drawn as the benchmark figures of docs/results.md draw
them (24 runs per effect, 30 clean): a winding heating as the integral of i^2 and an
inductance saturating piecewise, both visible in the run (residual visibility above
one noise RMS) but only in segments the default split fits; a quadratic drag whose
offset a load torque takes; a Coulomb friction behind a filtered current sensor.
"""

from __future__ import annotations

from functools import cache

import pytest

from pmdc_ident.benchmark.cases import Case, build_cases, record
from pmdc_ident.benchmark.runner import write_recording
from pmdc_ident.core.diagnosis import DiagnosisConfig, VerdictStatus, diagnose, pipeline
from pmdc_ident.core.diagnosis.holdout import split_segments, swapped
from pmdc_ident.dataio import load_data


@cache
def _cases(seed: int = 1) -> dict[str, Case]:
    # the draws of docs/results.md's benchmark figures (24 runs per effect, 30 clean)
    return {c.name: c for c in build_cases(24, 30, 4, 12, seed)}


@cache
def _record(name: str, seed: int):  # type: ignore[no-untyped-def]
    # the record and its visibility (a fit of the best linear motor): read only, and
    # resistance_drift_03 serves two tests
    return record(_cases(seed)[name])


def _segments(name: str, tmp_path, seed: int = 1):  # type: ignore[no-untyped-def]
    case = _cases(seed)[name]
    rec, vis = _record(name, seed)
    run = load_data(write_recording(rec, tmp_path / f"{name}.csv"))
    return case, vis, list(run.segments)


@pytest.fixture
def looks(monkeypatch):  # type: ignore[no-untyped-def]
    """Every look diagnose takes on a split (``pipeline._diagnose_split``'s results, in
    order; a second look stopped before its candidates returns none): the checks of a
    look read diagnose's own instead of repeating it (~1-2 CPU-s each)."""
    seen = []
    real = pipeline._diagnose_split

    def spy(*args, **kwargs):  # type: ignore[no-untyped-def]
        seen.append(real(*args, **kwargs))
        return seen[-1]

    monkeypatch.setattr(pipeline, "_diagnose_split", spy)
    return seen


@pytest.mark.parametrize(
    "name",
    [
        "resistance_drift_03",  # 4 % of R, heating from the first seconds on
        "inductance_saturation_22",  # L falls 35 % at peak current: the opening step
    ],
)
def test_an_effect_only_the_fitted_side_shows_is_named_with_the_sides_swapped(name, tmp_path):
    case, vis, segs = _segments(name, tmp_path)
    assert vis is not None and vis.residual > 1.0  # the effect is in the record
    res = diagnose(segs)
    assert res.verdict.status is VerdictStatus.EXPLAINED
    assert res.verdict.effects[0] == case.effects[0].name
    # the swapped split is looked at only after the default one found no gap
    # (pipeline.diagnose), so the default split alone would have said no_gap
    assert res.split.rule == "swapped"
    assert "swapped" in res.verdict.message
    assert res.gap_after < 0.5 * res.gap_before


def test_a_gap_only_the_swapped_side_shows_with_no_effect_to_name_it_is_no_gap(tmp_path, looks):
    # a clean 250 Hz motor: fitted on the held-out side alone, the linear model misses
    # the fitted side by noise variances (that side holds the opening step, whose
    # initial speed is read off the encoder's first counts), yet no effect explains it
    # and the default side fits its own segments: the default split, built to span
    # every regime, decides. (Reading a start from rest as never turning backwards
    # removed this miss, and named a Coulomb friction on an effect-free coreless motor
    # at 10 kHz, the generator's seed-2 clean_24: not done.)
    _, _, segs = _segments("clean_23", tmp_path)
    res = diagnose(segs)
    assert res.verdict.status is VerdictStatus.NO_GAP
    assert res.split.rule == "default"
    # the second look diagnose took, fitted on the held-out side (from the first look's
    # baseline), and the split it judged
    first, alone = looks
    assert first.split.rule == "default"
    assert alone.split.to_json() == swapped(split_segments(segs)).to_json()
    assert alone.verdict.status is VerdictStatus.UNEXPLAINED and alone.gap_before > 1.0


def test_an_out_of_vocabulary_effect_only_the_fitted_side_shows_is_unexplained(tmp_path, looks):
    # MuJoCo's torque saturation (an equation nobody here wrote; no candidate limits the
    # torque) on a 12 V gearmotor, the blind draw's torque_saturation_01: it cuts the
    # opening step and the sweep's first quarter, both fitted by the default split,
    # which finds no gap (0.3 noise variances); fitted on the other side, the linear
    # model misses them by 6.6 and no candidate closes that: unexplained, not no_gap
    pytest.importorskip("mujoco")
    from pmdc_ident.benchmark.mujoco_cases import build_mj_cases, record_mj

    case = next(c for c in build_mj_cases(24, 30, 4, 12, 2) if c.name == "torque_saturation_01")
    assert case.kind == "oov"
    rec, vis = record_mj(case)
    assert vis is not None and vis.residual > 1.0
    segs = list(load_data(write_recording(rec, tmp_path / "ts.csv")).segments)
    res = diagnose(segs)
    first = looks[0]  # diagnose's first look: the default split
    assert first.split.to_json() == split_segments(segs).to_json()  # the default split
    assert first.verdict.status is VerdictStatus.NO_GAP
    assert res.verdict.status is VerdictStatus.UNEXPLAINED
    assert res.verdict.effects == ()
    assert res.split.rule == "swapped"
    assert "swapped" in res.verdict.message and res.gap_before > 1.0


def test_a_split_the_user_chose_is_never_swapped(tmp_path):
    # held out: the odd staircase levels and the step down, where the heating leaves no
    # gap (0.44 noise variances); swapped, these sides name it (2.3), which would be
    # taken if a user's split were swapped as the default one is. (The split held out
    # before, the even levels and the sweep, explained the heating on the first look:
    # nothing to swap, and the test passed without the rule.)
    _, _, segs = _segments("resistance_drift_03", tmp_path)
    cfg = DiagnosisConfig(holdout=("staircase_01", "staircase_03", "staircase_05", "step_down"))
    res = diagnose(segs, config=cfg)
    assert res.verdict.status is VerdictStatus.NO_GAP
    assert res.split.rule == "user"
    assert "swapped" not in res.verdict.message


@pytest.mark.parametrize(
    ("name", "note"),
    [
        # the backward step: a load torque is the best single effect (it takes the
        # drag's offset over the held-out staircase); the drag added to it closes the
        # rest, but the drag alone does as well as the pair: the load only stood in
        # for part of the drag, and naming both would blame a load that is not there
        ("quadratic_drag_08", ""),
        # the chain's lag on top: the current sensor's filter lags a fraction of a
        # sample; alone that lag closes a little of the gap, the friction most of it
        # but not enough; the lag on top of the friction, kept as the chain's lag and
        # unnamed, explains it (combined as a delay effect it was judged as one)
        ("coulomb_friction_11", "(chain lag)"),
    ],
)
def test_seed_2_runs_the_second_looks_name(name, note, tmp_path):
    case, vis, segs = _segments(name, tmp_path, seed=2)
    assert vis is not None and vis.residual > 1.0
    res = diagnose(segs)
    assert res.verdict.status is VerdictStatus.EXPLAINED
    assert res.verdict.effects == (case.effects[0].name,)
    assert note in res.verdict.message
    assert res.gap_after < 0.5 * res.gap_before


def test_a_swapped_side_whose_gap_no_effect_could_beat_fits_no_candidate(tmp_path):
    # clean_00: the swapped baseline misses its held-out side by 0.03 noise variances,
    # less than one parameter's penalty, so no candidate could be named there: the
    # second look stops after its baseline (same verdict, half the work)
    _, _, segs = _segments("clean_00", tmp_path)
    said: list[str] = []
    res = diagnose(segs, progress=said.append)
    assert res.verdict.status is VerdictStatus.NO_GAP
    i = next(k for k, m in enumerate(said) if "sides of the split swapped" in m)
    assert any("no effect can be named" in m for m in said[i:])
    assert not any(m.startswith("candidate") for m in said[i:])
    assert any(m.startswith("candidate") for m in said[:i])  # the first look fits them
