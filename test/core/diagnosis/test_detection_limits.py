"""Detection limits (issue 25): a ``no_gap`` says what the record could have shown, and
the sizes it names are calibrated: an effect twice the limit leaves a gap, one a third
of it does not."""

from __future__ import annotations

import math

import pytest
from helpers.plans import TINY_SEQUENCE

from pmdc_ident.core.diagnosis import DiagnosisConfig, VerdictStatus, diagnose
from pmdc_ident.core.effects import DEFAULT_CANDIDATES, LoadTorque
from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor

SPEC = load_motor("seed001_110v")


def _run(model, seed: int = 1):  # type: ignore[no-untyped-def]
    return synthesize_run(
        model, plan_for_motor(SPEC, 1e-3, TINY_SEQUENCE), SPEC.sensors, seed=seed
    )


@pytest.fixture(scope="module")
def clean():  # type: ignore[no-untyped-def]
    return diagnose(_run(SPEC.model))


def test_a_no_gap_carries_a_limit_for_every_effect_of_the_vocabulary(clean):
    assert clean.verdict.status is VerdictStatus.NO_GAP
    limits = {d.effect: d for d in clean.detection_limits}
    assert list(limits) == list(DEFAULT_CANDIDATES)
    assert "none above these sizes" in clean.verdict.message
    doc = clean.to_json()["detection_limits"]
    assert set(doc) == set(DEFAULT_CANDIDATES)
    for name, d in limits.items():
        if d.size is not None:
            assert d.size > 0 and math.isfinite(d.size), name
            assert d.relative is not None and d.relative > 0
            assert name in clean.verdict.message
    assert doc["load_torque"]["unit"] == "N*m"


@pytest.mark.parametrize(("factor", "gap"), [(3.0, True), (0.3, False)])
def test_the_limit_is_calibrated_on_the_diagnosis_itself(clean, factor, gap):
    """A load torque above the limit leaves a gap the diagnosis sees (never no_gap);
    one well below it does not."""
    limit = next(d for d in clean.detection_limits if d.effect == "load_torque").size
    assert limit is not None
    model = SPEC.model.with_effects(LoadTorque(factor * limit))
    res = diagnose(_run(model), config=DiagnosisConfig(detection_limits=False))
    assert (res.verdict.status is not VerdictStatus.NO_GAP) is gap, res.verdict.message


def test_an_opt_in_effect_gets_its_limit_too():
    """An effect outside the default candidates, asked for, is sized like the others (its
    missing size once dropped the whole table without a word)."""
    cfg = DiagnosisConfig(effects=(*DEFAULT_CANDIDATES, "torque_dependent_friction"))
    res = diagnose(_run(SPEC.model), config=cfg)
    limits = {d.effect: d for d in res.detection_limits}
    assert list(limits) == [*DEFAULT_CANDIDATES, "torque_dependent_friction"]
    lim = limits["torque_dependent_friction"]
    assert lim.size is None or 0 < lim.size < 1, lim


def test_a_stribeck_fall_above_the_limit_is_seen_where_the_default_split_fits_it(clean):
    """A Gaussian fall (MuJoCo's LuGre curve) shows in the breakaway from rest, a segment
    the default split fits: the swapped side alone sees it on held-out data, and no
    Stribeck torque can be fitted there. Such a gap was once counted: the limit read
    0.48 N*m and a fall of 1.5x that ended ``no_gap`` (gap 0.5 noise variances)."""
    from pmdc_ident.core.effects import StribeckFriction
    from pmdc_ident.core.effects.stribeck_friction import DETECTION_SPEED

    lim = next(d for d in clean.detection_limits if d.effect == "stribeck_friction")
    assert lim.size is not None
    assert "Gaussian" in lim.detail
    top = max(float(abs(s.speed_or_derivative()).max()) for s in _run(SPEC.model).segments)
    effect = StribeckFriction(1.5 * lim.size, DETECTION_SPEED * top, 2.0)
    res = diagnose(
        _run(SPEC.model.with_effects(effect)), config=DiagnosisConfig(detection_limits=False)
    )
    assert res.verdict.status is not VerdictStatus.NO_GAP, (lim.size, res.verdict.message)
