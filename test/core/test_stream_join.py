"""StampJoiner: the driver's three topics joined by stamp, in order, losses bounded."""

from __future__ import annotations

import numpy as np

from pmdc_ident.core.stream_join import StampJoiner


def test_samples_arriving_in_any_order_come_out_complete_and_sorted() -> None:
    j = StampJoiner()
    for ns in (3, 1, 2):
        j.add("speed", ns * 1_000_000, 10.0 * ns)
    for ns in (2, 3, 1):
        j.add("current", ns * 1_000_000, float(ns))
    j.add("voltage", 1_000_000, 0.5)
    j.add("voltage", 3_000_000, 1.5)
    t, v, i, w = j.take()  # sample 3 waits for sample 2, which is still incomplete
    assert np.allclose(t, [1e-3]) and np.allclose(v, [0.5]) and np.allclose(w, [10])
    j.add("voltage", 2_000_000, 1.0)
    t, v, i, w = j.take()
    assert np.allclose(t, [2e-3, 3e-3]) and np.allclose(i, [2, 3])
    assert j.dropped == 0


def test_a_lost_message_drops_its_sample_after_the_hold_time() -> None:
    j = StampJoiner(hold_s=0.05)
    for k in range(100):  # 1 ms samples; the voltage of sample 10 is lost
        for kind in ("voltage", "current", "speed"):
            if not (k == 10 and kind == "voltage"):
                j.add(kind, k * 1_000_000, float(k))
    t = j.take()[0]
    assert t.size == 99 and j.dropped == 1
    assert np.all(np.diff(t) > 0)


def test_nan_voltage_of_an_open_armature_is_a_value() -> None:
    j = StampJoiner()
    for kind in ("voltage", "current", "speed"):
        j.add(kind, 5, float("nan") if kind == "voltage" else 1.0)
    t, v, _, _ = j.take()
    assert t.size == 1 and np.isnan(v[0])


def test_pending_samples_are_bounded() -> None:
    j = StampJoiner(max_pending=10)
    for ms in range(100):
        j.add("current", ms * 1_000_000, 1.0)  # the other topics never come
    assert j.take()[0].size == 0
    assert j.dropped == 90  # beyond max_pending
    for kind in ("voltage", "current", "speed"):
        j.add(kind, 1_000_000_000, 1.0)
    assert j.take()[0].size == 1  # the rest fell 0.1 s behind the newest stamp
    assert j.dropped == 100
