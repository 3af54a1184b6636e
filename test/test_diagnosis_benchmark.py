"""The withheld-effect benchmark: draws, run files without truth, scoring (small N)."""

from __future__ import annotations

import numpy as np
import pytest

from pmdc_ident.commands.benchmark import (
    ARCHETYPES,
    Case,
    Outcome,
    _scales,
    draw_effect,
    generate_cases,
    run_case,
    score,
)
from pmdc_ident.core.diagnosis import DiagnosisConfig
from pmdc_ident.core.effects import EFFECT_NAMES, CoulombFriction


def test_drawn_magnitudes_lie_in_the_documented_ranges():
    p, vmax, _, _ = ARCHETYPES["ebike_24v"]
    s = _scales(p, vmax)
    rng = np.random.default_rng(0)
    for _ in range(50):
        tc = draw_effect("coulomb_friction", p, vmax, 1000.0, rng).torque_nm
        assert 0.05 * s["T_r"] <= tc <= 0.3 * s["T_r"]
        vb = draw_effect("brush_drop", p, vmax, 1000.0, rng).voltage_v
        assert 0.5 <= vb <= 3.0
        d = draw_effect("delay", p, vmax, 1000.0, rng).delay_s
        assert 2e-3 <= d <= 20e-3
        cog = draw_effect("cogging", p, vmax, 1000.0, rng)
        # the cogging frequency at top speed stays within a quarter of the sample rate
        assert cog.periods_per_rev * s["w0"] / (2 * np.pi) <= 1000.0 / 4 + 1e-9
    # seed 000's own Coulomb torque is inside the drawn range
    assert 0.05 * s["T_r"] <= 0.0256 <= 0.3 * s["T_r"]


def test_generated_cases_cover_the_vocabulary_clean_runs_and_pairs():
    cases = generate_cases(1, 2, 2, seed=4)
    singles = [c.truth[0] for c in cases if len(c.truth) == 1]
    assert sorted(singles) == sorted(EFFECT_NAMES)
    assert sum(1 for c in cases if not c.truth) == 2
    assert sum(1 for c in cases if len(c.truth) == 2) == 2
    for c in cases:
        if "inductance_saturation" in c.truth:  # only where L/R spans >= 2 samples
            assert c.params.electrical_time_constant_s >= 2.0 / c.rate_hz


def _outcome(truth: tuple[str, ...], effects: tuple[str, ...], shrink: float) -> Outcome:
    p, vmax, _, _ = ARCHETYPES["hobby_12v"]
    drawn = tuple(draw_effect(n, p, vmax, 500.0, np.random.default_rng(0)) for n in truth)
    case = Case("x", "hobby_12v", p, drawn, 500.0, 1.0, vmax, 0)
    return Outcome(case, "explained" if effects else "no_gap", effects, shrink, 0.0)


def test_score_counts_top1_false_attribution_and_median_shrink():
    outs = [
        _outcome(("coulomb_friction",), ("coulomb_friction",), 0.9),
        _outcome(("coulomb_friction",), ("coulomb_friction",), 0.7),
        _outcome(("coulomb_friction",), ("load_torque",), 0.8),
        _outcome((), (), 0.0),
        _outcome((), ("delay",), 0.3),
        _outcome((), (), 0.0),
        _outcome((), (), 0.0),
    ]
    sc = score(outs)
    assert sc.per_effect["coulomb_friction"] == (2, 3)
    assert sc.top1 == pytest.approx(2 / 3)
    assert sc.false_attribution == pytest.approx(0.25)
    assert sc.median_shrink_right == pytest.approx(0.8)
    assert sc.confusion["coulomb_friction"] == {"coulomb_friction": 2, "load_torque": 1}
    assert sc.confusion["none"] == {"no_gap": 3, "delay": 1}
    assert "| coulomb_friction | 67% | 3 |" in sc.table()


def test_smoke_run_file_holds_no_truth_and_the_diagnosis_finds_the_effect(tmp_path):
    p, vmax, _, _ = ARCHETYPES["hobby_12v"]
    s = _scales(p, vmax)
    case = Case("smoke", "hobby_12v", p, (CoulombFriction(0.15 * s["T_r"]),), 500.0, 1.0, vmax, 7)
    out = run_case(
        case, tmp_path, DiagnosisConfig(effects=("coulomb_friction", "load_torque", "brush_drop"))
    )
    text = next(tmp_path.glob("*.csv")).read_text()
    assert "coulomb" not in text and "smoke" not in text
    assert out.top1 == "coulomb_friction"
    assert out.shrink > 0.7
