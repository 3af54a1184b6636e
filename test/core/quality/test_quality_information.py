"""Expected uncertainty before the fit (the gate's Cramer-Rao bound) against the fit itself.

Records from the independent RK4 motor (``motor_records``); the bound is computed by
the gate's own numpy simulator (``core.quality.linsim``), the fit by the package's
output-error engine, so agreement is a check of both.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from helpers.motor_records import Motor, prbs, simulate, steps, write_csv

from pmdc_ident.cli import main
from pmdc_ident.core.quality.information import (
    advice_for,
    expected_information,
    rate_for_inductance_hz,
)
from pmdc_ident.core.quality.linsim import first_order_scan, zoh, zoh_response
from pmdc_ident.dataio.units import load_input


def test_linsim_matches_a_plain_loop():
    rng = np.random.default_rng(0)
    for lam in (0.999, 1.0, 0.9 + 0.3j, 1e-3, 1e-250):
        w = rng.normal(size=3000) + 0j
        z = np.empty(3000, dtype=complex)
        z[0] = 0.3
        for k in range(2999):
            z[k + 1] = lam * z[k] + w[k]
        np.testing.assert_allclose(first_order_scan(lam, w, 0.3), z, rtol=0, atol=1e-12 * 3000)
    # a motor step against its closed-form two-pole answer at the samples
    r, ind, ke, j, b = 2.0, 2e-3, 0.05, 2e-5, 2e-6
    a = np.array([[-r / ind, -ke / ind], [ke / j, -b / j]])
    phi, gam = zoh(a, np.array([[1 / ind], [0.0]]), 1e-3)
    y = zoh_response(phi, gam, np.eye(2), np.full((400, 1), 6.0), np.zeros(2))
    lam, vec = np.linalg.eig(a)
    x_inf = -np.linalg.solve(a, np.array([6.0 / ind, 0.0]))
    t = np.arange(400) * 1e-3
    exact = (
        x_inf[None, :] - (vec @ np.diag(np.linalg.solve(vec, x_inf)) @ np.exp(np.outer(lam, t))).T
    )
    np.testing.assert_allclose(y, exact.real, rtol=1e-9, atol=1e-9)


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A 1 kHz record of steps and a coast, its expected sd and the fit's standard errors."""
    v = steps([6, 12, None, -6, 0], 0.4, 1000)
    rec = simulate(Motor(Tc=0.002), v, 1000, noise_current=0.005, noise_speed=0.05)
    path = write_csv(tmp_path_factory.mktemp("info") / "run.csv", rec, drop=("position",))
    js = path.with_suffix(".json")
    rc = main(["identify", str(path), "--json", str(js), "--quiet", "--no-holdout"])
    assert rc == 0
    return json.loads(js.read_text())


def test_expected_sd_before_the_fit_matches_the_fits_standard_errors(fitted):
    expected = fitted["quality"]["expected_rsd"]
    for name in ("R", "L", "Ke", "J"):
        p = fitted["parameters"][name]
        se = p["stderr"] / p["value"]
        assert 0.5 < expected[name] / se < 2.0, (name, expected[name], se)


def test_inductance_at_5_khz_is_identifiable_from_the_data_not_a_rule_of_thumb(tmp_path):
    """L/R = 0.14 ms < 0.2 ms sample period: the bound says L is pinned (issue 9)."""
    m = Motor(R=3.5, L=0.49e-3, Ke=0.012, Kt=0.012, J=1e-6, B=1e-8)
    rec = simulate(m, steps([3, 6, -3], 0.05, 5000), 5000, noise_current=0.002, noise_speed=0.2)
    x = load_input(write_csv(tmp_path / "fast.csv", rec, drop=("position",)))
    info = expected_information(x.run.segments)
    assert info is not None and info.tau_e_resolved
    assert info.values["L"] == pytest.approx(0.49e-3, rel=0.2)
    assert info.rsd["L"] < 0.10


def test_50_hz_prbs_says_l_is_not_resolved_and_what_to_record(tmp_path, capsys):
    m = Motor(R=8.0, L=2e-3, Ke=0.008, Kt=0.008, J=2e-7, B=1e-8, Tc=2e-5)
    rec = simulate(m, prbs(500, 6.0, 1, seed=3), 50, substeps=100, noise_current=0.003)
    q = 2 * math.pi / 12 / 0.02  # speed from a 12-count encoder over one 20 ms sample
    rec.speed = np.round(rec.speed / q) * q
    path = write_csv(tmp_path / "prbs50.csv", rec, drop=("position",))
    rc = main(["check", str(path), "--ignore", "speed-counts"])
    out = capsys.readouterr().out
    assert rc == 0
    assert "warning: speed-counts:" in out  # whole counts per sample (a mean), ignored here
    line = next(ln for ln in out.splitlines() if "identifiability" in ln and " L: " in ln)
    assert line.strip().startswith("info:")
    assert "L/R is not resolved at this rate: at best weakly identifiable" in line
    assert "sample at least 10x faster (>= 500 Hz) or --fix L=" in line
    assert "speed moves in steps of 26.18 rad/s" in out


def test_rate_for_inductance_grows_as_the_bound_tightens():
    tau, dt = 0.2e-3, 1e-3
    r1 = rate_for_inductance_hz(0.5, tau, dt, 0.10)
    r2 = rate_for_inductance_hz(0.5, tau, dt, 0.02)
    assert 1 / dt < r1 < r2 < math.inf
    assert rate_for_inductance_hz(0.05, tau, dt, 0.10) == pytest.approx(1 / dt)


def test_50_hz_with_a_faster_rotor_says_j_is_not_resolved(tmp_path, capsys):
    """tau_m = 5 ms sampled every 20 ms: the speed settles within a sample."""
    m = Motor(R=8.0, L=2e-3, Ke=0.008, Kt=0.008, J=4e-8, B=1e-8, Tc=2e-5)
    rec = simulate(m, prbs(300, 6.0, 1, seed=3), 50, substeps=100, noise_current=0.003)
    rc = main(["check", str(write_csv(tmp_path / "fast.csv", rec, drop=("position",)))])
    out = capsys.readouterr().out
    assert rc == 0
    line = next(ln for ln in out.splitlines() if "identifiability" in ln and " J: " in ln)
    assert "the mechanical time constant is not resolved at this rate: at best weakly" in line
    assert "sample at least 10x faster (>= 500 Hz)" in line


def test_l_rate_advice_resolves_the_smallest_l_the_interval_allows():
    """The fit's advice for L plans the rate for the low end of L's 95 % interval. An L
    the data do not bound (87 % relative sd, L/R 3.7 us as fitted from a 0.7 us motor
    at 1 kHz) needs MHz there: only the meter is advice (the estimate alone said
    75 kHz). A weakly identifiable L still gets a rate; an enormous sd no error."""
    unbounded = advice_for("L", 0.867, tau_e=3.65e-6, dt_s=1e-3)
    assert unbounded.startswith("fix L from an LCR meter") and "sample at" not in unbounded
    weak = advice_for("L", 0.2, tau_e=2e-4, dt_s=1e-3)
    assert weak.startswith("sample at >= ") and "LCR meter" in weak
    assert "LCR meter" in advice_for("L", 1e4, tau_e=2e-4, dt_s=1e-3)  # exp(-1.96 rsd) = 0


def test_l_rate_advice_for_an_l_bounded_by_nothing_is_the_meter_not_an_overflow():
    # relative sd 200 on L/R = 0.2 ms at 1 kHz: the interval's low end is exp(-392) L,
    # its ratio squared beyond the float range; it raised OverflowError inside the
    # fit (diagnose: "the baseline linear model could not be fitted ... (34, ...)")
    assert "LCR meter" in advice_for("L", 200.0, tau_e=2e-4, dt_s=1e-3)
    assert rate_for_inductance_hz(1e200, 1e-9, 1e-3, 0.10) == pytest.approx(2.0 / 1e-9)
