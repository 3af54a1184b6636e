"""The current-unit check on a long record: the record's own resistance (issue 22) is
fitted only where the amperes are in doubt, and on a long record from windows spread
over it (issue 28: the regression over every sample of a 3.7 M-row log raised `check`'s
peak memory from 0.5 to 1.45 GB)."""

from __future__ import annotations

import numpy as np
import pytest

import pmdc_ident.core.quality.regress as regress
from pmdc_ident.core.data import Segment
from pmdc_ident.core.quality.scales import check_magnitudes

R, L, KE = 0.01, 2e-5, 0.05  # a 15 V, 10 milliohm motor drawing up to 1000 A


def _record(n: int, amps: float) -> Segment:
    rng = np.random.default_rng(3)
    dt = 1e-3
    t = np.arange(n) * dt
    levels = rng.uniform(0.3, 1.0, n // 500 + 1).repeat(500)[:n]
    i = amps * levels + rng.normal(0, 0.01 * amps, n)
    w = 60.0 + 40.0 * np.sin(2 * np.pi * t / 7.0)
    v = R * i + L * np.gradient(i, dt) + KE * w
    return Segment("run", t, v, current=i, speed=w)


@pytest.fixture
def fits(monkeypatch) -> list[int]:
    """The samples each resistance fit is given."""
    seen: list[int] = []
    real = regress.electrical_fit

    def counted(segments):  # type: ignore[no-untyped-def]
        seen.append(sum(s.n for s in segments))
        return real(segments)

    monkeypatch.setattr(regress, "electrical_fit", counted)
    return seen


def test_no_resistance_fit_where_the_amperes_are_not_in_doubt(fits):
    found = check_magnitudes("log.csv", [_record(20_000, 5.0)], frozenset())
    assert not [f for f in found if f.code == "current-unit"]
    assert fits == []


def test_a_long_record_fits_its_resistance_on_spread_windows_with_the_same_verdict(fits):
    long = _record(600_000, 1000.0)
    found = check_magnitudes("log.csv", [long], frozenset())
    # 1000 A at 15 V is doubted; its own 10 milliohm make it plausible (stall 1500 A)
    assert not [f for f in found if f.code == "current-unit"]
    assert len(fits) == 1 and fits[0] <= 250_000
    short = check_magnitudes("log.csv", [_record(100_000, 1000.0)], frozenset())
    assert not [f for f in short if f.code == "current-unit"]
    assert fits[1] == 100_000  # a record that fits the budget is read whole
