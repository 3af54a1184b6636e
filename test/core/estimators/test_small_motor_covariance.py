"""A 0.45 W coreless motor (B ~ 2e-8 N*m*s/rad, J ~ 1.5e-8 kg*m^2): the output-error
fit's covariance is taken on the information scaled to a unit diagonal, so R, Ke and J
are reported with intervals, not as 'singular' (the raw eigenvalue tolerance was set by
B's and the friction's absolute-unit columns, 1e10 larger than the rest)."""

from __future__ import annotations

import pytest

from pmdc_ident.benchmark.motors import MOTORS
from pmdc_ident.core.effects import CoulombFriction
from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
from pmdc_ident.core.identification.identify import identify
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import Limits, MotorSpec, SensorSpec


def test_a_sub_watt_motor_is_identified_with_intervals():
    m = MOTORS["coreless_6v"]
    p = m.params
    model = Model(p, (CoulombFriction(p.B * m.speed_no_load_rad_s),))
    spec = MotorSpec("coreless", model, SensorSpec(1e-3, 0.0, 4096.0),
                     Limits(6.0, 0.45, 2.0 * m.speed_no_load_rad_s))  # fmt: skip
    run = synthesize_run(model, plan_for_motor(spec, 1 / 2000.0), spec.sensors, seed=1,
                         signals=("current", "position"))  # fmt: skip
    res = identify(list(run.segments), fixed={"L": p.L}, holdout=False, frequency=False)
    for name in ("R", "Ke", "J", "B"):
        e = res.parameters[name]
        assert e.identifiable and e.stderr is not None, (name, e.reason)
        assert e.value == pytest.approx(getattr(p, name), rel=0.05)
        assert e.stderr / e.value < 0.05
