"""A gap below one noise energy of the signals is still named when the held-out data show
the effect."""

from __future__ import annotations

import pytest

from pmdc_ident.core.diagnosis import VerdictStatus, diagnose
from pmdc_ident.core.effects import ResistanceDrift
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import Limits, MotorSpec, SensorSpec
from pmdc_ident.core.params import MotorParams

# A 12 V hobby motor at 500 Hz with R rising ~25 % over a shortened session (the case
# of the former built-in benchmark, seed 1, kept as a regression test).
PARAMS = MotorParams(2.2025925, 1.2175007e-3, 0.013387012, 0.013387012, 3.8414567e-6, 2.382515e-7)
DRIFT = ResistanceDrift(0.035187616)
SENSORS = SensorSpec(current_noise_a=0.0058510971, speed_noise_rad_s=0.058510971)
PLAN = SequenceConfig(sweep_duration_tau=20.0, staircase_hold_tau=4.0, step_hold_tau=5.0)


def test_resistance_drift_below_the_noise_energy_is_named_when_held_out_data_show_it():
    # Relative to the signals' energy the baseline's held-out gap is half the noise
    # energy (the old unit: 2.0e-4 against 3.9e-4), which once read as "no gap". In
    # noise variances per signal (the gap's unit now) the current's excess is many
    # noise variances, and the drift fitted without the held-out samples closes it
    # there, beyond its penalty.
    limits = Limits(voltage_max_v=12.0, current_max_a=1e4, speed_max_rad_s=1e5)
    plan = plan_for_motor(MotorSpec("hobby", Model(PARAMS), SENSORS, limits), 1 / 500.0, PLAN)
    run = synthesize_run(Model(PARAMS, (DRIFT,)), plan, SENSORS, seed=1823309227)
    r = diagnose(run)
    gap0 = r.to_json()["holdout"]["gap_before"]
    assert gap0 > 1.0
    assert r.verdict.status is VerdictStatus.EXPLAINED
    assert r.verdict.effects == ("resistance_drift",)
    got = {p.name: p.value for p in r.augmented}["resistance_drift.coeff_per_a2s"]
    assert got == pytest.approx(DRIFT.coeff_per_a2s, rel=0.05)
