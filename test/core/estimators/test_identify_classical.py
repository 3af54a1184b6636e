"""Seed 000's classical chain on its real measured tables (Table 4, retardation test)."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.paths import FIXTURES

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.estimators.classical import (
    classical_chain,
    coast_speed,
    fit_coastdown,
    fit_staircase,
    steady_state_points,
)
from pmdc_ident.dataio import load_data

FIX = FIXTURES
PAPER_KE = 0.0662  # V*s/rad, seed 000 Table 6
PAPER_J = 0.00099  # kg*m^2, seed 000 Table 6 (one average slope)


@pytest.fixture(scope="module")
def seed000_segments() -> tuple[Segment, ...]:
    stair = load_data(FIX / "seed000_table4.csv")
    coast = load_data(FIX / "seed000_retardation.csv")
    return stair.segments + coast.segments


def test_table4_gives_ke_within_1_percent_of_paper(seed000_segments):
    pts = steady_state_points(seed000_segments)
    assert len(pts) == 12
    fit = fit_staircase(pts, R=1.375)  # the paper's multimeter R
    assert fit.Ke == pytest.approx(PAPER_KE, rel=0.01)
    assert fit.Ke_ci95[0] < PAPER_KE < fit.Ke_ci95[1]


def test_table4_ke_without_multimeter_r_still_within_1_percent(seed000_segments):
    fit = fit_staircase(steady_state_points(seed000_segments))
    assert fit.Ke == pytest.approx(PAPER_KE, rel=0.01)
    assert fit.R_fitted and fit.R_ci95 is not None


def test_table4_friction_is_coulomb_plus_viscous_consistent_with_the_table(seed000_segments):
    fit = fit_staircase(steady_state_points(seed000_segments), R=1.375)
    # Kt*i at the lowest level (w = 23 rad/s) is 0.023 N*m: almost all of it Coulomb
    assert fit.Tc == pytest.approx(0.0252, abs=0.001)
    assert fit.Tc_ci95[0] > 0.02  # the intercept is real, not noise
    # the paper's B = 0.00007 N*m*s/rad lies in the interval
    assert fit.B_ci95[0] < 7e-5 < fit.B_ci95[1]
    # the line reproduces Table 4's torques (0.023-0.048 N*m) to 2e-3 N*m rms (6 %)
    assert fit.rms_torque_nm < 2.5e-3


def test_retardation_j_with_table4_friction_and_its_interval(seed000_segments):
    res = classical_chain(seed000_segments, fixed={"R": 1.375})
    coast = res.coast
    assert coast is not None
    # Coulomb + viscous deceleration with Table-4 friction implies J ~ 3.9e-4 kg*m^2,
    # well below the paper's 0.00099 (which used one average slope and P_m = 24.52 W)
    assert coast.J == pytest.approx(3.87e-4, rel=0.03)
    lo, hi = coast.J_ci95
    assert lo < coast.J < hi
    assert hi < PAPER_J  # the paper's J is inconsistent with its own Table 4 friction
    assert coast.average_slope_rad_s2 == pytest.approx(3150 * np.pi / 30 / 3.6, rel=1e-6)
    assert any("coast-down" in n for n in res.notes)


def test_coast_speed_closed_form_stops_at_predicted_time():
    a, c, w0 = 0.5, 20.0, 100.0
    t_stop = np.log(1 + a * w0 / c) / a
    t = np.array([0.0, t_stop * 0.5, t_stop * 1.01, t_stop * 2])
    w = coast_speed(t, w0, a, c)
    assert w[0] == w0 and w[2] == 0.0 and w[3] == 0.0
    assert w[1] == pytest.approx((w0 + c / a) * np.exp(-a * t[1]) - c / a)


def test_coastdown_recovers_j_from_a_simulated_curve():
    J, Tc, B = 2e-3, 0.03, 1e-4
    t = np.linspace(0, 8, 200)
    w = coast_speed(t, 300.0, B / J, Tc / J)
    seg = Segment("coast", t, np.full(t.size, np.nan), speed=w)
    fit = fit_coastdown(seg, Tc=Tc, B=B)
    assert fit.J == pytest.approx(J, rel=1e-6)
    assert fit.J_from_Tc == pytest.approx(J, rel=1e-3)


def test_staircase_without_speed_change_is_refused():
    t = np.arange(3.0)
    segs = [
        Segment(f"staircase_0{k}", t, np.full(3, 2.0), current=np.full(3, 0.3), speed=np.ones(3))
        for k in range(1, 4)
    ]
    with pytest.raises(DataError, match="same speed"):
        fit_staircase(steady_state_points(segs))
