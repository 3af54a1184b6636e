"""The lead-in of a held-out prediction: LEAD_IN_TAU mechanical time constants of the
piece of the record just before the held-out segment, never its first sample."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis.leadin import LEAD_IN_TAU, lead_ins

DT = 1e-3


def _record(n: int = 400) -> Segment:
    t = np.arange(n) * DT
    v = np.where(t < 0.2, 2.0, 6.0) + 0.01 * np.arange(n)  # every sample's command unique
    return Segment("rec", t, v, current=np.sin(t), speed=np.cos(t))


@pytest.mark.parametrize("tau_s", [2 * DT, 1e-3 * DT, math.nan])
def test_one_piece_is_enough_or_nothing_is_taken(tau_s):
    rec = _record()
    before, held = rec.slice(0, 300), rec.slice(300, 400)
    (lead,) = lead_ins([before, held], [held], tau_s)
    if not math.isfinite(tau_s):
        assert lead.samples == 0 and lead.segment is held
        return
    need = max(2, math.ceil(LEAD_IN_TAU * tau_s / DT))
    assert lead.samples == need
    np.testing.assert_array_equal(lead.segment.t, rec.t[300 - need :])


def test_a_held_out_segment_that_starts_the_record_has_no_lead_in():
    rec = _record()
    held, after = rec.slice(0, 100), rec.slice(100, 400)
    (lead,) = lead_ins([held, after], [held], 10 * DT)
    assert lead.samples == 0 and lead.segment is held


def test_the_lead_in_never_starts_on_the_first_sample_of_a_record():
    """Where the record before is shorter than the lead-in asked for, all but its
    first sample are taken (the state is read off the lead-in's first samples)."""
    rec = _record()
    first, held = rec.slice(0, 20), rec.slice(20, 400)
    (lead,) = lead_ins([first, held], [held], 10 * DT)
    assert lead.samples == 19
    np.testing.assert_array_equal(lead.segment.t, rec.t[1:])
