"""The pmdc serial protocol: CRC, COBS, message round trips, parser robustness (fuzzed)."""

from __future__ import annotations

import pytest
from helpers.paths import REPO
from hypothesis import given, settings
from hypothesis import strategies as st

from pmdc_ident.protocol import (
    PROTOCOL_VERSION,
    TELEMETRY_WIRE_BYTES,
    Ack,
    Boot,
    CrcError,
    ErrorReply,
    FrameParser,
    Hello,
    HelloAck,
    OpenArmature,
    Ping,
    Pong,
    ProtocolError,
    SetDuty,
    SetVoltage,
    StartStream,
    StopStream,
    Telemetry,
    VersionMismatchError,
    cobs_decode,
    cobs_encode,
    crc16_ccitt_false,
    decode_frame,
    encode_frame,
    frame_message,
    min_period_us,
    parse_frame,
)
from pmdc_ident.protocol.codec import MAX_ENCODED_BYTES

ALL_MESSAGES = [
    Hello(PROTOCOL_VERSION),
    StartStream(2605, 500),
    StopStream(),
    SetVoltage(-12345),
    SetDuty(-32767),
    OpenArmature(),
    Ping(0xDEADBEEF),
    Ack(0x04),
    HelloAck(1, 15, 7, 2605, 4096, 0.001, 0.002, 24.0, 24.0),
    Telemetry(2**32 - 1, 123456, -(2**31), -32768, 32767, 0, -1, 0x7F),
    Pong(1, 2),
    ErrorReply(0x02, 4, 2605),
    Boot(1, 3),
]


def test_crc16_ccitt_false_matches_the_standard_check_value() -> None:
    assert crc16_ccitt_false(b"123456789") == 0x29B1
    assert crc16_ccitt_false(b"") == 0xFFFF


@pytest.mark.parametrize(
    ("raw", "encoded"),
    [
        (b"\x00", b"\x01\x01"),
        (b"\x00\x00", b"\x01\x01\x01"),
        (b"\x11\x22\x00\x33", b"\x03\x11\x22\x02\x33"),
        (b"\x11\x22\x33\x44", b"\x05\x11\x22\x33\x44"),
        (bytes(range(1, 255)), b"\xff" + bytes(range(1, 255)) + b"\x01"),
    ],
)
def test_cobs_matches_the_published_examples(raw: bytes, encoded: bytes) -> None:
    assert cobs_encode(raw) == encoded
    assert cobs_decode(encoded) == raw


@settings(deadline=None)  # timing varies on a loaded CI machine
@given(st.binary(max_size=600))
def test_cobs_round_trip_has_no_zero_and_bounded_overhead(data: bytes) -> None:
    enc = cobs_encode(data)
    assert 0 not in enc
    assert len(enc) <= len(data) + 1 + len(data) // 254
    assert cobs_decode(enc) == data


@pytest.mark.parametrize("msg", ALL_MESSAGES, ids=lambda m: type(m).__name__)
def test_every_message_round_trips_through_a_frame(msg: object) -> None:
    wire = frame_message(msg, seq=200)  # type: ignore[arg-type]
    assert wire.endswith(b"\x00") and 0 not in wire[:-1]
    seq, back = parse_frame(wire[:-1])
    assert seq == 200
    if isinstance(msg, HelloAck):  # floats travel as float32
        assert back.current_lsb_a == pytest.approx(msg.current_lsb_a, rel=1e-7)
    else:
        assert back == msg


def test_telemetry_frame_is_27_bytes_and_the_rate_arithmetic_follows() -> None:
    # 2 header + 21 body + 2 CRC + 1 COBS + 1 delimiter = 27 bytes = 270 bits at 8N1.
    assert TELEMETRY_WIRE_BYTES == 27
    # 90 % of 115200 baud = 10368 bytes/s -> 384 frames/s -> 2605 us.
    assert min_period_us(115200) == 2605
    assert 1e6 / min_period_us(115200) == pytest.approx(383.9, abs=0.1)
    # 1 Mbaud: 300 us, 3333 Hz: 1 kHz and 2 kHz fit.
    assert min_period_us(1_000_000) == 300


def test_a_flipped_payload_bit_is_a_crc_error() -> None:
    wire = frame_message(SetVoltage(1000), 1)
    raw = bytearray(cobs_decode(wire[:-1]))
    raw[3] ^= 0x01
    with pytest.raises(CrcError):
        decode_frame(cobs_encode(bytes(raw)))


def test_wrong_length_and_unknown_type_are_protocol_errors() -> None:
    with pytest.raises(ProtocolError, match="expected 4"):
        parse_frame(encode_frame(b"\x04\x01\x00")[:-1])
    with pytest.raises(ProtocolError, match="unknown message type 0x55"):
        parse_frame(encode_frame(b"\x55\x01")[:-1])


def test_hello_ack_of_another_version_still_reports_its_version() -> None:
    payload = bytes((0x81, 3, 2)) + b"\x01" * 40  # a future v2 HELLO_ACK, longer body
    with pytest.raises(VersionMismatchError, match="v2; this host speaks v1") as info:
        parse_frame(encode_frame(payload)[:-1])
    assert info.value.version == 2


def test_out_of_range_field_is_a_protocol_error_not_a_struct_error() -> None:
    with pytest.raises(ProtocolError, match="SetDuty"):
        frame_message(SetDuty(40000))


def test_parser_resynchronises_after_garbage_and_truncated_frames() -> None:
    good = frame_message(Ping(7), 3)
    p = FrameParser()
    stream = b"\xff\x13\x37" + good[:5] + b"\x00" + good + good[: len(good) // 2] + good
    out = p.feed(stream)
    # garbage+truncated, then a good frame, then truncated-merged-with-good (lost), then ...
    assert [m for _, m in out].count(Ping(7)) >= 1
    s = p.stats
    assert s.frames_ok == len(out)
    assert s.errors >= 2
    # The line is clean again: the next frame decodes.
    assert p.feed(good) == [(3, Ping(7))]


def test_parser_gives_identical_results_for_any_chunking() -> None:
    wire = b"".join(frame_message(m, i) for i, m in enumerate(ALL_MESSAGES))
    whole = FrameParser().feed(wire)
    p = FrameParser()
    pieces = []
    for i in range(0, len(wire), 3):
        pieces += p.feed(wire[i : i + 3])
    assert len(whole) == len(ALL_MESSAGES)
    assert [(s, type(m)) for s, m in pieces] == [(s, type(m)) for s, m in whole]


def test_parser_drops_an_endless_frame_with_a_bounded_buffer() -> None:
    p = FrameParser()
    for _ in range(1000):
        p.feed(b"\x01" * 97)
        assert p.buffered_bytes <= MAX_ENCODED_BYTES
    assert p.stats.oversize_frames == 1
    assert p.feed(b"\x00" + frame_message(Ping(1))) == [(0, Ping(1))]


@settings(max_examples=400, deadline=None)
@given(st.lists(st.binary(max_size=200), max_size=30), st.integers(0, 2**32 - 1))
def test_fuzzed_bytes_never_crash_the_parser_or_grow_its_buffer(
    chunks: list[bytes], token: int
) -> None:
    p = FrameParser()
    for c in chunks:
        for seq, item in p.feed(c):
            assert 0 <= seq <= 255
            assert item is not None
        assert p.buffered_bytes <= MAX_ENCODED_BYTES
    # Whatever came before, a delimiter and a valid frame decode again.
    assert p.feed(b"\x00" + frame_message(Ping(token), 9)) == [(9, Ping(token))]


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=1, max_size=64))
def test_fuzzed_valid_crc_payloads_decode_or_raise_protocol_error(payload: bytes) -> None:
    try:
        parse_frame(encode_frame(payload)[:-1])
    except ProtocolError:
        pass


@settings(deadline=None)
@given(
    st.integers(0, 2**32 - 1),
    st.integers(-(2**31), 2**31 - 1),
    st.integers(-32767, 32767),
    st.integers(0, 255),
)
def test_telemetry_fields_round_trip_exactly(
    counter: int, count: int, current: int, faults: int
) -> None:
    msg = Telemetry(counter, counter ^ 0xFFFF, count, current, -current, 0, 1, faults)
    assert parse_frame(frame_message(msg)[:-1]) == (0, msg)


def test_one_fault_enum_whose_bits_are_the_firmwares():
    """The protocol, every backend and the driver carry pmdc_ident.core.enums.Fault; its
    bits must be the firmware's PMDC_FAULT_* values (the wire format)."""
    import re

    from pmdc_ident.backends import base, sim
    from pmdc_ident.backends.serial_link import decoder, delivery
    from pmdc_ident.core.enums import Fault
    from pmdc_ident.protocol import board

    header = REPO / "firmware" / "protocol" / "pmdc_protocol.h"
    firmware = {
        name: int(value)
        for name, value in re.findall(r"PMDC_FAULT_(\w+)\s*=\s*(\d+)", header.read_text())
    }
    assert firmware == {f.name: f.value for f in Fault if f.value}
    for module in (base, decoder, delivery, sim, board):
        assert module.Fault is Fault, module.__name__
    assert board.STICKY_FAULTS == Fault.OVER_CURRENT | Fault.OVER_SPEED | Fault.WATCHDOG
