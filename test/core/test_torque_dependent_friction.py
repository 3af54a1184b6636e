"""torque_dependent_friction: the effect added through the registry alone (issue 26).

Checked against records integrated by ``test/helpers/motor_records.py`` (RK4 with the
friction ``mu |Kt i|`` in its own equations, no code of the package): the kernel
reproduces them, the diagnosis names the effect where the records hold it (when asked
to try it: an opt-in candidate) and not where they hold a Coulomb friction instead.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers.motor_records import Motor, prbs, simulate, steps

from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis import DiagnosisConfig, VerdictStatus, diagnose
from pmdc_ident.core.effects import (
    DEFAULT_CANDIDATES,
    EFFECT_TYPES,
    CoulombFriction,
    TorqueDependentFriction,
)
from pmdc_ident.core.model import Model
from pmdc_ident.core.model import simulate as simulate_model
from pmdc_ident.core.params import MotorParams

RATE = 1000.0
# L/R = 5 ms: five samples, resolved at 1 kHz
MOTOR = dict(R=2.0, L=1e-2, Ke=0.05, Kt=0.05, J=2e-5, B=2e-6)
WITH_IT = (*DEFAULT_CANDIDATES, "torque_dependent_friction")


def _voltage() -> np.ndarray:
    """A staircase (motoring), a reversal and a PRBS (braking), a coast-down."""
    return np.concatenate(
        [
            steps([3.0, 6.0, 9.0, 12.0], 0.15, RATE),
            steps([-12.0, 0.0], 0.2, RATE),
            prbs(1200, 8.0, 15, seed=3),
            steps([12.0, None], 0.3, RATE),
        ]
    )


def _segments(m: Motor, seed: int = 5) -> list[Segment]:
    rec = simulate(
        m, _voltage(), RATE, substeps=20, noise_current=0.01, noise_speed=0.2, seed=seed
    )
    whole = Segment("log", rec.t, rec.voltage, current=rec.current, speed=rec.speed)
    bounds = [(0, 600, "staircase"), (600, 1000, "reversal"), (1000, 2200, "prbs"),
              (2200, 2500, "step"), (2500, 2800, "coast")]  # fmt: skip
    return [whole.slice(a, b, label=label) for a, b, label in bounds]


def test_the_kernel_reproduces_an_independent_integration_of_the_friction():
    m = Motor(**MOTOR, Tc=0.002, mu=0.3)
    v = _voltage()
    rec = simulate(m, v, RATE, substeps=40)
    p = MotorParams(**MOTOR)
    both = Model(p, (CoulombFriction(0.002), TorqueDependentFriction(0.3)))
    sim = simulate_model(both, v, 1 / RATE)
    without = simulate_model(Model(p, (CoulombFriction(0.002),)), v, 1 / RATE)
    top = float(np.max(np.abs(rec.speed)))
    err = float(np.max(np.abs(sim.speed - rec.speed)))
    effect = float(np.max(np.abs(without.speed - rec.speed)))
    assert err < 5e-3 * top  # the sub-stepped kernel against RK4
    assert effect > 20 * err  # and the effect is far larger than that
    assert np.max(np.abs(sim.current - rec.current)) < 5e-3 * np.max(np.abs(rec.current))


def test_it_is_an_opt_in_candidate():
    assert "torque_dependent_friction" in EFFECT_TYPES
    assert "torque_dependent_friction" not in DEFAULT_CANDIDATES
    assert "torque_dependent_friction" not in DiagnosisConfig().effects
    assert DiagnosisConfig(effects=WITH_IT).effects[-1] == "torque_dependent_friction"


@pytest.mark.parametrize("mu", [0.1, 0.3])
def test_the_diagnosis_names_it_alone_where_the_records_hold_it(mu):
    r = diagnose(_segments(Motor(**MOTOR, mu=mu)), config=DiagnosisConfig(effects=WITH_IT))
    assert r.verdict.status is VerdictStatus.EXPLAINED, r.verdict.message
    assert r.verdict.effects == ("torque_dependent_friction",)
    got = {p.name: p.value for p in r.augmented}
    assert got["torque_dependent_friction.loss_ratio"] == pytest.approx(mu, rel=0.1)


def test_a_coulomb_friction_is_not_taken_for_it():
    r = diagnose(_segments(Motor(**MOTOR, Tc=0.004)), config=DiagnosisConfig(effects=WITH_IT))
    assert r.verdict.status is VerdictStatus.EXPLAINED, r.verdict.message
    assert r.verdict.effects[0] == "coulomb_friction"
    assert "torque_dependent_friction" not in r.verdict.effects
