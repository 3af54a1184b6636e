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


# -- one policy: the on-line and offline joins agree ------------------------------------
def _streams(holes: dict[str, set[int]], n: int = 200):
    """Topics at 1 kHz (voltage k, current 2k, speed 3k at sample k), with holes."""
    ns = np.arange(n, dtype=np.int64) * 1_000_000
    keep = {t: np.array([k not in holes.get(t, set()) for k in range(n)]) for t in holes}
    return ns, keep


def test_the_monitor_join_and_the_bag_join_keep_the_same_samples_and_count_the_same_holes():
    from pmdc_ident.core.samples import DriverSamples
    from pmdc_ident.core.stream_join import join_driver_samples

    holes = {"voltage": {50}, "current": {120, 121}, "speed": {77}}
    ns, keep = _streams(holes)
    k = np.arange(ns.size, dtype=float)
    j = StampJoiner(hold_s=0.05)
    for i in range(ns.size):
        for kind, scale in (("voltage", 1.0), ("current", 2.0), ("speed", 3.0)):
            if keep[kind][i]:
                j.add(kind, int(ns[i]), scale * k[i])
    t, v, cur, w = j.take()
    samples = DriverSamples(
        current_ns=ns[keep["current"]],
        current_a=2.0 * k[keep["current"]],
        encoder_ns=ns[keep["speed"]],
        position_rad=np.zeros(int(keep["speed"].sum())),
        speed_rad_s=3.0 * k[keep["speed"]],
        voltage_ns=ns[keep["voltage"]],
        voltage_v=k[keep["voltage"]],
        terminal_v=None,
        markers=(),
    )
    off = join_driver_samples(samples)
    assert np.array_equal(np.round(t * 1e9).astype(np.int64), off.stamps)
    assert np.array_equal(v, off.columns["voltage"])
    assert np.array_equal(cur, off.columns["current"])
    assert np.array_equal(w, off.columns["speed"])
    assert j.dropped == off.missing == 4


def test_the_controllers_held_current_is_the_offline_held_value():
    from pmdc_ident.core.stream_join import HeldStream, held_at

    rng = np.random.default_rng(0)
    ns = np.cumsum(rng.integers(1, 5, 300)).astype(np.int64) * 1_000_000
    values = rng.normal(size=ns.size)
    queries = np.sort(rng.integers(int(ns[0]), int(ns[-1]) + 3_000_000, 500)).astype(np.int64)
    stream = HeldStream()
    out, added = [], 0
    for q in queries:  # every sample stamped at or before the query has arrived
        while added < ns.size and ns[added] <= q:
            stream.add(int(ns[added]), float(values[added]))
            added += 1
        out.append(stream.at(int(q), float("nan")))
    assert np.array_equal(np.array(out), held_at(ns, values, queries))


def test_the_monitor_join_thins_to_a_slower_topic_and_counts_every_sample_left_out():
    """The one difference from the offline join (module doc): no rule 3 on line."""
    j = StampJoiner(hold_s=0.01)
    for k in range(100):
        for kind in ("current", "speed") + (("voltage",) if k % 2 == 0 else ()):
            j.add(kind, k * 1_000_000, float(k))
    t = j.take()[0]  # samples 91-99 ms are within hold_s of the newest: still waiting
    assert np.array_equal(np.round(t * 1e3), np.arange(0, 91, 2))
    assert j.dropped == 45  # every odd sample up to 89 ms: said, not silent
