"""A named effect must be one the record could show (``pipeline._showable``).

The fixture is a reveal plan's effect-free record played on MuJoCo's ``<dcmotor>``
(``benchmarks/bench_design.py --reveal --plant mujoco --effects stribeck_friction
--clean``, seed 7, run 3: the 12 V gearmotor, 1.33 s at 250 Hz, a 512-count encoder and
a quantised current). Its winding's L/R is a sixth of a sample, yet an inductance
saturation "closed 84 %" of a gap held in the last 7 samples of a square wave, while
the same result's detection limits read "inductance_saturation not shown at any
size"."""

from __future__ import annotations

from helpers.paths import FIXTURES

from pmdc_ident.core.diagnosis import DiagnosisConfig, diagnose
from pmdc_ident.core.diagnosis.results import VerdictStatus
from pmdc_ident.dataio import load_data

RECORD = FIXTURES / "mujoco_gearmotor_250hz_short_plan.csv"


def test_an_effect_the_record_cannot_show_is_not_named():
    res = diagnose(load_data(RECORD))
    assert res.verdict.status is not VerdictStatus.EXPLAINED, res.verdict
    assert "inductance_saturation" not in res.verdict.effects
    assert "could not show inductance_saturation at any size" in res.verdict.message
    # the limit the rule reads is the one the result reports
    (lim,) = [x for x in res.detection_limits if x.effect == "inductance_saturation"]
    assert lim.size is None
    # what is reported is the linear motor's fit, not the unsupported candidate's
    aug = {p.name: p.value for p in res.augmented}
    base = {p.name: p.value for p in res.baseline}
    assert aug == base


def test_the_check_is_part_of_the_verdict_not_of_the_report():
    # with the limits left out of the result, the verdict is the same
    res = diagnose(load_data(RECORD), config=DiagnosisConfig(detection_limits=False))
    assert res.verdict.status is not VerdictStatus.EXPLAINED, res.verdict
    assert "could not show inductance_saturation at any size" in res.verdict.message
    assert res.detection_limits == ()
