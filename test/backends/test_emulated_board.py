"""The reference sketch on an emulated ATmega328P (simavr) against the motor part.

Two ways in: the rig's scripted host (``pmdc_emu --host``, free-running, exact:
drops, refusals, watchdog and missed encoder counts are counted by the emulator
itself), and the real host (:class:`SerialBackend`) over the pty in real time,
with the fault paths (AVR reset, paused board, pulled cable) and the emulator's
lifetime. Skipped in one line where the AVR tools or simavr are not installed
(``.ci/run`` installs them on CI).
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path
from typing import Any

import pytest

from pmdc_ident.backends.base import BackendError
from pmdc_ident.backends.emulated_board import EmulatedBoard, build_firmware, tools_missing
from pmdc_ident.backends.serial_board import LinkState, SerialBackend
from pmdc_ident.core.enums import Fault
from pmdc_ident.core.motors import MotorSpec, load_motor

_MISSING = tools_missing()
pytestmark = [
    pytest.mark.skipif(_MISSING is not None, reason=f"emulated board: {_MISSING}"),
    pytest.mark.timeout(300),
]
BAUD = 1_000_000


@pytest.fixture(scope="module")
def motor() -> MotorSpec:
    return load_motor("seed000_ebike")


@pytest.fixture(scope="module")
def rig() -> tuple[Path, Path]:
    return build_firmware(BAUD)


def _scripted(rig: tuple[Path, Path], tmp: Path, *args: str) -> dict[str, Any]:
    elf, emu = rig
    stats = tmp / "stats.json"
    cmd = [str(emu), "--firmware", str(elf), "--baud", str(BAUD), "--free-run"]
    r = subprocess.run([*cmd, "--stats", str(stats), *args], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return json.loads(stats.read_text())


def test_the_sketch_streams_1khz_at_1mbaud_without_a_drop_or_a_missed_count(
    rig: tuple[Path, Path], tmp_path: Path
) -> None:
    s = _scripted(rig, tmp_path, "--host", "1000", "--step", "12,0.1", "--duration", "1.5")
    host, enc = s["host"], s["encoder"]
    assert host["frames"] >= 1450 and host["dropped"] == 0 and host["errors"] == 0
    assert host["parser_errors"] == 0
    assert enc["edges"] > 10_000 and enc["missed"] == 0 and enc["checks"] > 1000
    assert enc["emulator_double_edges"] == 0
    assert s["cpu"]["idle"] > 0.15  # headroom at 1 kHz, from cycle counts
    assert 0 < s["latency_us"]["max"] < 2000  # command frame -> bridge reprogrammed
    # every count latched at its grid instant (the timer's interrupt, D11), whatever the
    # loop was busy with, and the conversions started soon after it (D13)
    cap, start = s["timing"]["capture_late_us"], s["timing"]["start_late_us"]
    assert cap["n"] >= 1450 and start["n"] >= 1450
    assert cap["max"] - cap["min"] < 30 and -5 < cap["min"] and cap["max"] < 40
    assert start["max"] < 150
    # a new setpoint reaches the bridge at the sample after it, once that sample's current
    # is in: applied_v is what the bridge holds over the period (the host's ZOH)
    bridge = s["timing"]["bridge_after_capture_us"]
    assert bridge["n"] >= 10 and 50 < bridge["min"] and bridge["max"] < 300
    # the telemetry's count is the shaft's (a few samples behind the end)
    behind = enc["emitted"] - host["last_encoder_count"]
    assert 0 <= behind < 0.01 * enc["emitted"]


def test_the_board_refuses_a_period_below_its_own_limit(
    rig: tuple[Path, Path], tmp_path: Path
) -> None:
    s = _scripted(rig, tmp_path, "--host", "990", "--duration", "0.2")
    assert s["host"]["frames"] == 0 and s["host"]["errors"] == 1


def test_the_encoder_follows_its_documented_edge_rate_while_streaming(
    rig: tuple[Path, Path], tmp_path: Path
) -> None:
    # shaft driven 0 -> 290 rad/s (94 500 edges/s at 2048 counts/rev) at the fastest period
    s = _scripted(rig, tmp_path, "--host", "1000", "--ramp", "290,0.6,0.1", "--duration", "0.9")
    assert s["encoder"]["max_edge_rate"] > 90_000
    assert s["encoder"]["missed"] == 0
    assert s["host"]["dropped"] == 0


def test_the_watchdog_opens_the_armature_when_the_host_goes_silent(
    rig: tuple[Path, Path], tmp_path: Path
) -> None:
    s = _scripted(
        rig,
        tmp_path,
        "--host",
        "1000",
        "--step",
        "6,10",
        "--host-silent-at",
        "0.3",
        "--duration",
        "1.0",
    )
    # 500 ms after the host's last frame (the default watchdog), within a loop turn
    assert 0.500 <= s["host"]["open_after_last_frame_s"] <= 0.502
    assert 0.3 < s["host"]["open_after_silent_s"] <= 0.502
    assert s["host"]["watchdog_s"] > 0  # and the telemetry says WATCHDOG


@pytest.fixture
def board(motor: MotorSpec) -> Any:
    b = EmulatedBoard(motor, baud=BAUD).start()
    yield b
    b.close()
    b.cleanup()


def _collect(be: SerialBackend, seconds: float, volts: float | None) -> list[Any]:
    out: list[Any] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if volts is None:
            be.open_armature()
        else:
            be.command_voltage(volts)
        out += be.poll()
        time.sleep(0.01)
    return out


def test_a_short_session_over_the_real_host_matches_the_motor_part(
    board: EmulatedBoard, motor: MotorSpec
) -> None:
    be = SerialBackend(board.port, BAUD, dt_s=0.001)
    be.start()
    try:
        assert be.board_info is not None and be.board_info.min_period_us == 1000
        up = _collect(be, 2.0, 12.0)
        coast = _collect(be, 0.8, None)
        stats = be.link_stats
    finally:
        be.close()
    board.close()
    emu = board.stats()
    assert emu is not None and emu["stalled_s"] == 0.0
    # The board dropped nothing; a test process starved by a busy machine may still
    # have let the pty overflow (bytes the emulator could not write: counted).
    assert stats.dropped_samples == 0 or emu["uart"]["lost"] > 0
    assert stats.crc_errors == 0 or emu["uart"]["lost"] > 0
    p = motor.model.params
    tail = up[-300:]
    w = sum(s.speed_rad_s for s in tail) / len(tail)
    i = sum(s.current_a for s in tail) / len(tail)
    v = sum(s.voltage_cmd_v for s in tail) / len(tail)
    assert v == pytest.approx(12.0)
    # steady state of the part's equations: V = R i + Ke w (PWM, ADC and encoder between)
    assert w == pytest.approx((v - p.R * i) / p.Ke, rel=0.02)
    assert i == pytest.approx((motor.model.effects[0].torque_nm + p.B * w) / p.Kt, abs=0.06)
    # coasting: open armature, no current, the rotor slows down
    late = coast[-100:]
    assert all(math.isnan(s.voltage_cmd_v) for s in late)
    assert all(abs(s.current_a) < 0.06 for s in late)
    assert late[-1].speed_rad_s < w


def test_an_avr_reset_is_reported_once_and_the_host_streams_again(board: EmulatedBoard) -> None:
    # a generous host timeout: the reset must be told by the BOOT frame, not by silence
    be = SerialBackend(
        board.port, BAUD, dt_s=0.002, reconnect_interval_s=0.2, telemetry_timeout_s=3
    )
    be.start()
    try:
        _collect(be, 0.5, 6.0)
        board.reset()
        errors = []
        end = time.monotonic() + 8.0
        while time.monotonic() < end and (not errors or be.state is not LinkState.STREAMING):
            try:
                be.poll()
            except BackendError as exc:
                errors.append(str(exc))
            time.sleep(0.02)
        assert len(errors) == 1 and "reset" in errors[0], errors
        assert be.state is LinkState.STREAMING
        assert be.link_stats.board_resets >= 1
        # the rotor kept turning through the reset: no false OVER_SPEED on the new stream
        samples = _collect(be, 0.3, None)
        assert samples and not any(s.faults & Fault.OVER_SPEED for s in samples)
    finally:
        be.close()


def test_a_paused_board_trips_the_host_watchdog_then_comes_back(board: EmulatedBoard) -> None:
    be = SerialBackend(board.port, BAUD, dt_s=0.002, reconnect_interval_s=0.2)
    be.start()
    try:
        _collect(be, 0.3, 3.0)
        board.pause()
        time.sleep(1.2)
        with pytest.raises(BackendError, match="no telemetry"):
            for _ in range(100):
                be.poll()
                time.sleep(0.02)
        board.resume()
        end = time.monotonic() + 8.0
        while time.monotonic() < end and be.state is not LinkState.STREAMING:
            be.poll()
            time.sleep(0.05)
        assert be.state is LinkState.STREAMING
        # the board's own watchdog had opened the armature, and the host re-handshook
        samples = _collect(be, 0.3, None)
        assert samples and not (samples[-1].faults & Fault.OVER_CURRENT)
    finally:
        be.close()


def test_a_pulled_cable_is_one_line_and_never_hangs(board: EmulatedBoard) -> None:
    be = SerialBackend(board.port, BAUD, dt_s=0.002, reconnect=False)
    be.start()
    try:
        _collect(be, 0.3, 3.0)
        board.unplug()
        with pytest.raises(BackendError) as info:
            for _ in range(200):
                be.poll()
                time.sleep(0.01)
        assert "\n" not in str(info.value)
    finally:
        be.close()


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")  # a zombie has ended; only its reaping is left


def test_the_emulator_ends_with_its_parent(motor: MotorSpec, tmp_path: Path) -> None:
    pid_file = tmp_path / "emu.pid"
    script = textwrap.dedent(
        f"""
        import time
        from pmdc_ident.backends.emulated_board import EmulatedBoard
        from pmdc_ident.core.motors import load_motor
        b = EmulatedBoard(load_motor("seed000_ebike"), baud={BAUD}).start()
        open({str(pid_file)!r}, "w").write(str(b.proc.pid))
        time.sleep(60)
        """
    )
    parent = subprocess.Popen([sys.executable, "-c", script])
    try:
        end = time.monotonic() + 60
        while not pid_file.exists() and time.monotonic() < end:
            time.sleep(0.1)
        emu = int(pid_file.read_text())
        os.kill(emu, 0)  # running
        parent.send_signal(signal.SIGKILL)  # no clean-up code runs in the parent
        parent.wait(timeout=10)
        end = time.monotonic() + 5
        while time.monotonic() < end:
            if not _alive(emu):
                break
            time.sleep(0.05)
        else:
            os.kill(emu, signal.SIGKILL)
            pytest.fail("the emulator outlived its parent")
    finally:
        if parent.poll() is None:
            parent.kill()
