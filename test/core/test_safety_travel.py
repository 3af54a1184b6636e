"""The travel rule of the safety monitor (issue 25): a joint's measured position outside
its range trips at once and latches; no range, no rule."""

from __future__ import annotations

import math

import pytest

from pmdc_ident.core.enums import AbortReason
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.safety import SafetyConfig, SafetyMonitor


def test_the_measured_position_outside_the_range_trips_and_latches():
    m = SafetyMonitor(SafetyConfig(10.0, 100.0, position_min_rad=-2.0, position_max_rad=2.0))
    assert m.check(0.0, 1.0, 5.0, 1.99) is None
    assert m.check(0.001, 1.0, 5.0, 2.01) is AbortReason.OUT_OF_TRAVEL
    assert "out of travel" in m.message() and m.tripped
    assert m.check(0.002, 1.0, 5.0, 0.0) is None  # latched: no new trip, still tripped
    assert m.tripped
    assert SafetyMonitor(m.config).check(0.0, 0.0, 0.0, math.nan) is AbortReason.OUT_OF_TRAVEL


def test_without_a_range_or_a_position_there_is_no_travel_rule():
    m = SafetyMonitor(SafetyConfig(10.0, 100.0))
    assert m.check(0.0, 1.0, 5.0, 1e6) is None
    ranged = SafetyMonitor(SafetyConfig(10.0, 100.0, position_min_rad=-1.0, position_max_rad=1.0))
    assert ranged.check(0.0, 1.0, 5.0) is None  # the driver reports no position


def test_a_range_must_be_min_below_max():
    with pytest.raises(ParameterError, match="travel"):
        SafetyConfig(10.0, 100.0, position_min_rad=1.0, position_max_rad=-1.0)
