"""Position wraps (`core.quality.signals.find_wrap`): a wrap is a jump back by one
period as the shaft turns, never an encoder's count of jitter on a shaft at rest."""

from __future__ import annotations

import math

import numpy as np

from pmdc_ident.core.quality.signals import find_wrap

COUNT = 2 * math.pi / 4800  # one count of a 4800-count encoder, in rad


def test_one_count_back_on_a_shaft_at_rest_is_no_wrap():
    # a reveal plan's slow level on MuJoCo's LuGre plant: 76 samples at rest, one count
    # back; the gate refused the record ("wraps 1 time(s) with a period of 0.001309")
    pos = np.full(76, 1.234 * COUNT * 1000)
    pos[40:] -= COUNT
    assert find_wrap(pos) is None
    # and jitter of one count both ways
    jitter = 500 * COUNT + COUNT * (np.arange(200) % 7 == 3)
    assert find_wrap(jitter) is None


def test_a_coarse_encoder_wrapping_in_counts_is_still_found():
    # a 12-count Hall encoder logged as its counter modulo 12, turning slowly forward
    counts = np.floor(np.linspace(0.0, 36.0, 2000, endpoint=False))
    found = find_wrap(np.mod(counts, 12.0))
    assert found is not None
    period, n = found
    assert n == 2 and abs(period - 12.0) <= 1.0  # within the one count it moved


def test_a_slow_turn_wrapping_at_one_turn_is_found_in_radians_and_degrees():
    theta = np.linspace(0.0, 3.5 * 2 * math.pi, 3000)
    theta = np.round(theta / COUNT) * COUNT
    for period in (2 * math.pi, 360.0):
        found = find_wrap(np.mod(theta * period / (2 * math.pi), period))
        assert found is not None and found[1] == 3
        assert abs(found[0] / period - 1.0) < 0.02
