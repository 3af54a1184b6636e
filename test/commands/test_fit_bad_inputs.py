"""Valid files that carry no information, and numbers that used to break a fit.

A flat, pico-scaled or almost never driven record is one line naming what is
missing, from identify and diagnose alike; starting values sized from data in
odd units, a diverged simulation and a perfect fit are numbers, not errors or
warnings.
"""

from __future__ import annotations

import math
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.core.data import Segment, check_excitation
from pmdc_ident.core.diagnosis.candidates import DataScales, starting_effects
from pmdc_ident.core.diagnosis.scoring import NoiseModel, Residuals
from pmdc_ident.core.effects import EFFECT_NAMES
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.identification.identify import minus_two_log_likelihood
from pmdc_ident.core.model import simulate
from pmdc_ident.core.motors import load_motor


def _record(scale: float = 1.0, open_after: int | None = None) -> dict[str, np.ndarray]:
    n, dt = 600, 2e-3
    v = np.full(n, 12.0)
    v[: n // 6] = 0.0
    v[n // 2 :] = 6.0
    v[5 * n // 6 :] = np.nan
    if open_after is not None:
        v[:open_after] = 12.0
        v[open_after:] = np.nan
    sim = simulate(load_motor("seed000_ebike").model, v, dt)
    out = {"t": np.arange(n) * dt, "voltage": v * scale, "current": sim.current * scale}
    out["speed"] = sim.speed * scale
    return out


def _csv(path, d: dict[str, np.ndarray]) -> str:
    cols = list(d)
    rows = [",".join(cols)]
    for k in range(d["t"].size):
        rows.append(",".join("" if np.isnan(d[c][k]) else repr(float(d[c][k])) for c in cols))
    path.write_text("\n".join(rows) + "\n")
    return str(path)


FLAT = {
    "every signal times 1e-300": (lambda: _record(scale=1e-300), "speed never changes"),
    "every signal times 1e-12 (pico units)": (lambda: _record(scale=1e-12), "never changes"),
    "driven for two samples, then open": (lambda: _record(open_after=2), "only 2 driven sample"),
}


@pytest.mark.parametrize("case", sorted(FLAT))
@pytest.mark.parametrize("command", ["identify", "diagnose", "check"])
def test_a_record_without_information_is_one_line(case, command, tmp_path, capsys):
    """check, identify and diagnose share one rule (core/data.excitation_problem)."""
    make, match = FLAT[case]
    quiet = [] if command == "check" else ["--quiet"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rc = main([command, _csv(tmp_path / "r.csv", make()), *quiet])
    err = capsys.readouterr().err
    assert not caught, [str(w.message) for w in caught]
    assert rc == EXIT_USER_ERROR, err
    assert err.strip().splitlines()[-1].startswith(f"pmdc-ident {command}: error:"), err
    assert match in err.strip().splitlines()[-1]
    if command == "check":
        assert "error: data quality: no-excitation:" in err and "fix: " in err


def test_excitation_check_keeps_a_real_record():
    d = _record()
    check_excitation([Segment("run", d["t"], d["voltage"], d["current"], speed=d["speed"])])
    with pytest.raises(DataError, match="never moves"):
        z = np.zeros(d["t"].size)
        check_excitation([Segment("run", d["t"], z, z, speed=z)])


@pytest.mark.parametrize("name", EFFECT_NAMES)
def test_starting_effects_stay_in_range_for_data_in_odd_units(name):
    # torque, voltage and current of mV/mA logs read as V/A, speed of a stalled rotor
    odd = DataScales(1e7, 1e5, 1e-6, 1e5, 1e-3, 1e-9, 60.0, (1,))
    for scales in (odd, DataScales(1e-9, 1e-9, 1e6, 1e-9, 1e-3, 1e12, 1e-3, (1,))):
        assert starting_effects(name, scales)  # each a valid effect, no range error


def test_a_diverged_simulation_is_a_large_finite_gap_without_warnings():
    noise = NoiseModel({"speed": 0.1}, {"speed": 10.0})
    res = Residuals({"speed": np.array([1e200, -1e250, 1.0])}, np.zeros(3, np.int64), noise)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gap = res.gap()
    assert math.isfinite(gap) and gap > 1e150


def test_a_perfect_fit_has_a_finite_likelihood():
    fit = SimpleNamespace(n_samples=100, rms={"current": 0.0, "speed": 1e-320})
    assert math.isfinite(minus_two_log_likelihood(fit))  # type: ignore[arg-type]


def test_irregular_sampling_says_where_instead_of_too_short(tmp_path, capsys):
    d = _record()
    d["t"][::7] += 0.0009  # a logger on a busy PC: every 7th stamp late by 45 % of a period
    rc = main(["identify", _csv(tmp_path / "r.csv", d), "--quiet", "--no-auto-segments"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert rc == EXIT_USER_ERROR
    assert "gaps in time" in err and "worst: " in err and "median period 0.002 s" in err


class _Bowl:
    """A one-parameter least-squares problem whose simulation diverges beyond z = 0.8
    (residual 1e300, sensitivities inf), as a motor model does in odd corners."""

    n_total = n_global = 1
    bounds = [(-5.0, 5.0)]

    def __init__(self, start_diverges: bool = False) -> None:
        self.start_diverges = start_diverges

    def clip(self, z):
        return np.clip(z, -5.0, 5.0)

    def limit_step(self, step):
        return step

    def evaluate(self, z, want_jac):
        bad = z[0] > 0.8 or self.start_diverges
        r = np.array([1e300 if bad else z[0] - 2.0, 0.1])
        if not want_jac:
            return r, None, None
        j = np.array([[np.inf if bad else 1.0], [0.0]])
        return r, np.where(bad, np.inf, 1.0) * np.ones((1, 1)), j[0] * r[:1]


def test_the_solver_refuses_a_diverged_start_in_one_line():
    from pmdc_ident.core.estimators.solver import LMSettings, levenberg_marquardt

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(DataError, match="the fit cannot start"):
            levenberg_marquardt(_Bowl(start_diverges=True), np.zeros(1), LMSettings(20))


def test_the_solver_steps_back_from_diverged_trial_points():
    from pmdc_ident.core.estimators.solver import LMSettings, levenberg_marquardt

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        z, state = levenberg_marquardt(_Bowl(), np.zeros(1), LMSettings(50))
    assert np.isfinite(z).all() and 0.0 < z[0] <= 0.8 and math.isfinite(state.cost)
