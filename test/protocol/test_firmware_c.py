"""The portable C protocol core, built with the host gcc, against the Python side.

Shared vectors in firmware/test/vectors/ are generated from Python
(firmware/test/gen_vectors.py). Checked both ways: the C encoder reproduces
the Python bytes and Python decodes what C wrote; the C decoder recovers the
Python fields. The C board state machine answers a 300-step script with the
same bytes as the Python board. A fuzz run under ASan/UBSan, an AVR build of
the core, and a full Uno build of the sketch (when avr-gcc and the Debian
arduino-core-avr package are installed; skipped otherwise) follow.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest
from helpers.paths import REPO

from pmdc_ident.protocol import parse_frame
from pmdc_ident.protocol.messages import MESSAGE_TYPES, Message

FW = REPO / "firmware"
CORE = FW / "protocol" / "pmdc_protocol.c"
HARNESS = FW / "test" / "pmdc_host_test.c"
VECTORS = FW / "test" / "vectors"
CFLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-pedantic", "-O2"]

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="no host gcc")


def _gen() -> ModuleType:
    spec = importlib.util.spec_from_file_location("gen_vectors", FW / "test" / "gen_vectors.py")
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _build(out: Path, extra: list[str] | None = None) -> Path:
    cmd = ["gcc", *CFLAGS, *(extra or []), "-I", str(FW / "protocol"), str(HARNESS), str(CORE)]
    result = subprocess.run([*cmd, "-lm", "-o", str(out)], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    return out


@pytest.fixture(scope="module")
def harness(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _build(tmp_path_factory.mktemp("c") / "pmdc_host_test")


def _run(exe: Path, *args: str) -> list[str]:
    r = subprocess.run([str(exe), *args], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    return r.stdout.splitlines()


def _vector_lines() -> list[list[str]]:
    text = (VECTORS / "messages.txt").read_text().splitlines()
    return [ln.split() for ln in text if ln and not ln.startswith("#")]


def _f32(x: float) -> float:
    return struct.unpack("<f", struct.pack("<f", x))[0]


def _same_fields(msg: Message, fields_text: list[str]) -> bool:
    values = msg._values()
    if len(values) != len(fields_text):
        return False
    for v, text in zip(values, fields_text, strict=True):
        if isinstance(v, float):
            if _f32(v) != _f32(float(text)):
                return False
        elif v != int(text):
            return False
    return True


def test_committed_vectors_are_what_the_python_side_generates_now() -> None:
    gen = _gen()
    committed = (VECTORS / "messages.txt").read_text().splitlines()
    assert committed == gen.message_lines()
    assert (VECTORS / "board_session.txt").read_text().splitlines() == gen.board_lines()
    assert len(_vector_lines()) >= 60


def test_core_compiles_warning_free_as_c99(tmp_path: Path) -> None:
    r = subprocess.run(
        ["gcc", *CFLAGS, "-c", str(CORE), "-o", str(tmp_path / "core.o")],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr


def test_c_encodes_the_same_bytes_and_python_decodes_them(harness: Path) -> None:
    vectors = _vector_lines()
    c_hex = _run(harness, "encode", str(VECTORS / "messages.txt"))
    assert len(c_hex) == len(vectors)
    for tok, got in zip(vectors, c_hex, strict=True):
        assert got == tok[-1], f"type {tok[0]}: C {got} != Python {tok[-1]}"
        seq, msg = parse_frame(bytes.fromhex(got)[:-1])
        assert seq == int(tok[1]) and int(msg.TYPE) == int(tok[0])
        assert _same_fields(msg, tok[2:-1]), (msg, tok)


def test_python_frames_decode_in_c_to_the_same_fields(harness: Path) -> None:
    vectors = _vector_lines()
    decoded = _run(harness, "decode", str(VECTORS / "messages.txt"))
    assert len(decoded) == len(vectors)
    for tok, line in zip(vectors, decoded, strict=True):
        got = line.split()
        assert got[:2] == tok[:2]
        _, msg = parse_frame(bytes.fromhex(tok[-1])[:-1])
        assert type(msg) is MESSAGE_TYPES[int(got[0])]
        assert _same_fields(msg, got[2:]), (line, tok)


def test_c_board_answers_byte_for_byte_like_the_python_board(harness: Path) -> None:
    script = (VECTORS / "board_session.txt").read_text().splitlines()
    ops = [ln for ln in script if ln and not ln.startswith("#")]
    expected = [ln.split("=>")[1].strip() for ln in ops]
    got = _run(harness, "board", str(VECTORS / "board_session.txt"))
    assert len(got) == len(expected) > 300
    mismatches = [(op, g, e) for op, g, e in zip(ops, got, expected, strict=True) if g != e]
    assert not mismatches, mismatches[:3]
    # The script really exercises the board: replies, telemetry and errors all occur.
    kinds = {bytes.fromhex(h)[1] for h in expected if h != "-"}  # first COBS data byte = type
    assert {0x80, 0x81, 0x82, 0x87, 0x8E, 0x8F} <= kinds


def test_c_parser_survives_fuzzing_under_sanitizers(tmp_path: Path) -> None:
    probe = subprocess.run(
        ["gcc", "-fsanitize=address,undefined", "-x", "c", "-", "-o", str(tmp_path / "p")],
        input="int main(void){return 0;}",
        capture_output=True,
        text=True,
    )
    if probe.returncode != 0:
        pytest.skip("gcc has no ASan/UBSan runtime here")
    exe = _build(tmp_path / "fuzz", ["-fsanitize=address,undefined", "-fno-sanitize-recover=all"])
    out = _run(exe, "fuzz", "12345", "300000")
    assert out and out[0].startswith("fuzz ok: 300000 bytes in")


def test_core_builds_for_the_avr_target_when_avr_gcc_is_installed(tmp_path: Path) -> None:
    if shutil.which("avr-gcc") is None:
        pytest.skip("avr-gcc not installed (apt: gcc-avr avr-libc)")
    r = subprocess.run(
        [
            "avr-gcc",
            "-mmcu=atmega328p",
            "-std=c99",
            "-Os",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-c",
            str(CORE),
            "-o",
            str(tmp_path / "core_avr.o"),
        ],
        capture_output=True,
        text=True,
    )
    assert r.returncode == 0, r.stderr


ARDUINO_AVR = Path("/usr/share/arduino/hardware/arduino/avr")  # Debian: arduino-core-avr


def test_sketch_builds_and_links_for_an_arduino_uno_when_the_avr_core_is_installed(
    tmp_path: Path,
) -> None:
    if shutil.which("avr-g++") is None or not (ARDUINO_AVR / "cores/arduino/Arduino.h").is_file():
        pytest.skip("avr-g++ or the Arduino AVR core not installed (apt: arduino-core-avr)")
    # The build CI and `virtual-board --emulated` use (the IDE's flags, the core as an
    # archive, -Wall -Wextra -Werror on the sketch and the protocol core).
    r = subprocess.run(
        [sys.executable, str(FW / "emulator" / "build.py"), "--baud", "1000000", "--json"],
        capture_output=True,
        text=True,
        env={**os.environ, "PMDC_FIRMWARE_CACHE": str(tmp_path)},
        timeout=600,
    )
    if r.returncode == 3:
        pytest.skip(r.stderr.strip())
    assert r.returncode == 0, r.stderr
    elf = Path(json.loads(r.stdout)["elf"])
    size = subprocess.run(["avr-size", str(elf)], capture_output=True, text=True).stdout
    text, data, bss = (int(x) for x in size.splitlines()[1].split()[:3])
    assert text + data <= 32256  # Uno flash minus the 512-byte boot loader
    assert data + bss <= 1536  # leave 512 of the 2048 bytes of RAM for the stack
    # Built once, then taken from the cache (content hash): nothing is rebuilt.
    again = subprocess.run(
        [sys.executable, str(FW / "emulator" / "build.py"), "--baud", "1000000", "--json"],
        capture_output=True,
        text=True,
        env={**os.environ, "PMDC_FIRMWARE_CACHE": str(tmp_path)},
        timeout=600,
    )
    assert again.returncode == 0 and json.loads(again.stdout)["elf"] == str(elf)
    assert json.loads(again.stdout)["cached"] is True


def test_the_emulated_boards_constants_are_the_sketchs() -> None:
    """virtual-board --emulated sizes its encoder and announces its rate from these."""
    import re

    from pmdc_ident.backends import emulated_board as eb

    text = (FW / "arduino" / "pmdc_board" / "pmdc_board.ino").read_text()

    def const(pattern: str) -> int:
        m = re.search(pattern, text)
        assert m is not None, pattern
        return int(m.group(1))

    assert const(r"HW_MIN_PERIOD_US = (\d+);") == eb.HW_MIN_PERIOD_US
    assert const(r"MAX_EDGE_RATE = (\d+)UL;") == eb.MAX_EDGE_RATE
    assert const(r"#define PMDC_COUNTS_PER_REV (\d+)UL") == eb.DEFAULT_COUNTS_PER_REV
