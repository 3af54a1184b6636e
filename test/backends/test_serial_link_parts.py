"""The serial backend's parts on their own: no port, no thread, no board.

The whole backend against a board is checked in test_serial_backend.py; here each
part's rule is pinned with numbers worked out by hand.
"""

from __future__ import annotations

import math

import pytest

from pmdc_ident.backends.base import BackendError, Telemetry
from pmdc_ident.backends.serial_link.decoder import SampleDecoder
from pmdc_ident.backends.serial_link.delivery import SampleQueue
from pmdc_ident.backends.serial_link.errors import LinkLostError, error_name, type_name
from pmdc_ident.backends.serial_link.reconnect import LinkState, Reconnection
from pmdc_ident.core.enums import Fault
from pmdc_ident.protocol import PROTOCOL_VERSION, HelloAck
from pmdc_ident.protocol import Telemetry as WireTelemetry
from pmdc_ident.protocol.messages import NOT_MEASURED

DT_S = 0.001
INFO = HelloAck(PROTOCOL_VERSION, 0, 3, 250, 1000, 0.001, 0.001, 24.0, 24.0)
RAD_PER_COUNT = 2.0 * math.pi / 1000


def _frame(counter: int, count: int, faults: int = 0, current: int = 500) -> WireTelemetry:
    return WireTelemetry(counter, 0, count, current, 12000, NOT_MEASURED, 24000, faults)


def _decoder(log: list[str] | None = None) -> SampleDecoder:
    dec = SampleDecoder(DT_S, "/dev/ttyTEST", (log if log is not None else []).append)
    dec.begin(INFO, now=100.0, lost_at=0.0)
    return dec


def test_samples_are_stamped_by_the_boards_counter_with_speed_over_the_interval():
    dec = _decoder()
    first = dec.decode(_frame(7, 1_000))
    second = dec.decode(_frame(8, 1_010))
    after_gap = dec.decode(_frame(11, 1_040))  # two frames lost on the wire
    assert first is not None and second is not None and after_gap is not None
    assert (first.sample_index, first.speed_rad_s, first.position_rad) == (0, 0.0, 0.0)
    assert second.time_s == pytest.approx(DT_S)
    assert second.speed_rad_s == pytest.approx(10 * RAD_PER_COUNT / DT_S)
    assert after_gap.sample_index == 4
    assert after_gap.speed_rad_s == pytest.approx(30 * RAD_PER_COUNT / (3 * DT_S))
    assert after_gap.position_rad == pytest.approx(40 * RAD_PER_COUNT)
    assert after_gap.faults & Fault.LINK and not second.faults & Fault.LINK
    assert dec.dropped == 2 and dec.samples_total == 3
    assert second.current_a == pytest.approx(0.5) and second.voltage_cmd_v == pytest.approx(12.0)
    assert math.isnan(second.terminal_voltage_v)


def test_the_encoder_count_wraps_at_32_bits_without_a_jump():
    dec = _decoder()
    dec.decode(_frame(1, 2**32 - 5))
    s = dec.decode(_frame(2, 5))
    assert s is not None and s.speed_rad_s == pytest.approx(10 * RAD_PER_COUNT / DT_S)


def test_a_counter_going_back_is_a_lost_link():
    dec = _decoder()
    dec.decode(_frame(50, 0))
    with pytest.raises(LinkLostError, match=r"counter went back \(50 -> 49\): board reset\?"):
        dec.decode(_frame(49, 0))


def test_a_resumed_stream_continues_the_time_axis_and_publishes_from_its_second_sample():
    dec = _decoder()
    for k in range(10):
        dec.decode(_frame(k, 20 * k))  # 10 samples, index 0..9, 180 counts turned
    dec.begin(INFO, now=100.5, lost_at=100.2)  # 0.3 s out: 300 periods on the board's grid
    assert dec.decode(_frame(0, 7)) is None  # the rotor may coast: one count is no speed
    s = dec.decode(_frame(1, 27))
    assert s is not None
    assert s.sample_index == 10 + 300 + 1
    assert s.position_rad == pytest.approx((180 + 20) * RAD_PER_COUNT)
    assert s.speed_rad_s == pytest.approx(20 * RAD_PER_COUNT / DT_S)


def test_a_new_sticky_fault_is_logged_once_and_a_link_error_flags_the_next_sample():
    log: list[str] = []
    dec = _decoder(log)
    dec.decode(_frame(1, 0, faults=int(Fault.WATCHDOG)))
    dec.flag_link()
    s = dec.decode(_frame(2, 0, faults=int(Fault.WATCHDOG)))
    assert log == ["serial board /dev/ttyTEST: board reports WATCHDOG (armature opened)"]
    assert s is not None and s.faults == Fault.WATCHDOG | Fault.LINK


def _sample(k: int) -> Telemetry:
    return Telemetry(k, k * DT_S, 0.0, 0.0, 0.0, 1.0)


def test_a_late_poll_gets_the_newest_samples_the_first_flagged():
    queue = SampleQueue(max_catch_up=3)
    for k in range(10):
        queue.put(_sample(k))
    out = queue.take()
    assert [s.sample_index for s in out] == [7, 8, 9]
    assert out[0].faults == Fault.LINK and out[1].faults == Fault.NONE
    assert queue.skipped == 7 and queue.take() == []


def test_a_lost_link_is_raised_once_after_the_samples_before_it():
    queue = SampleQueue(max_catch_up=100)
    queue.put(_sample(0))
    queue.report("serial port X failed")
    assert len(queue.take()) == 1  # the samples first
    with pytest.raises(BackendError, match="^serial port X failed$"):
        queue.take()
    assert queue.take() == []


def test_a_loss_while_streaming_is_reported_and_retried_on_schedule():
    link = Reconnection(enabled=True, interval_s=0.5)
    link.streaming()
    line = link.lose("gone", 10.0, fatal=False)
    assert line == "gone; motor commanded safe; reconnecting"
    assert link.state is LinkState.LOST and link.lost_at == 10.0
    assert link.wait_s(10.2) == pytest.approx(0.3)
    assert link.wait_s(10.5) == 0.0  # attempt now; the next one at 11.0
    assert link.lose("still gone", 10.6, fatal=False) is None  # reported once
    assert link.wait_s(10.7) == pytest.approx(0.4)


def test_a_fatal_loss_or_a_backend_that_may_not_reconnect_fails_for_good():
    link = Reconnection(enabled=True, interval_s=0.5)
    link.lose("v2 board", 1.0, fatal=True)
    assert link.state is LinkState.FAILED
    quiet = Reconnection(enabled=False, interval_s=0.5)
    quiet.streaming()
    assert quiet.lose("gone", 1.0, fatal=False) == "gone; motor commanded safe; not reconnecting"
    assert quiet.state is LinkState.FAILED


def test_wire_codes_are_named_in_messages():
    assert (error_name(4), error_name(250)) == ("RATE_TOO_HIGH", "error 250")
    assert (type_name(0x04), type_name(0xEE)) == ("SET_VOLTAGE", "type 0xee")
