"""Telemetry rate and command-to-telemetry latency through the virtual board.

    .venv/bin/python benchmarks/bench_serial.py [--seconds 3] [--commands 150]

For 115200 baud and 1 Mbaud: the host (SerialBackend over pyserial) streams
from `VirtualBoard` (pty, bytes paced to the baud) at the fastest period the
board accepts and at common rates, and reports

* sustained telemetry rate (samples received per second of wall time, gaps),
  against the reference: what the line itself can carry (27-byte frames at
  8N1) and the requested rate;
* command-to-telemetry latency: host writes SET_VOLTAGE -> the first sample
  whose applied voltage shows it arrives at the host (median, p95, max),
  against the floor a perfect UART gives: command wire time + mean wait for
  the next sample instant (period / 2) + telemetry wire time;
* PING round-trip time.
"""

from __future__ import annotations

import argparse
import signal
import statistics
import subprocess
import sys
import threading
import time

from pmdc_ident.backends.base import BackendError, Telemetry
from pmdc_ident.backends.serial_board import SerialBackend
from pmdc_ident.core.motors import load_motor
from pmdc_ident.protocol import TELEMETRY_WIRE_BYTES, SetVoltage, frame_message
from pmdc_ident.protocol import Telemetry as WireTelemetry
from pmdc_ident.protocol.messages import min_period_us


class _TimedBackend(SerialBackend):
    """Records the host arrival time of each sample's applied voltage (bench only)."""

    def __init__(self, *a: object, **kw: object) -> None:
        super().__init__(*a, **kw)  # type: ignore[arg-type]
        self.arrivals: list[tuple[float, float]] = []
        self.cond = threading.Condition()

    def _on_telemetry(self, t: WireTelemetry) -> Telemetry | None:
        sample = super()._on_telemetry(t)
        if sample is not None:
            with self.cond:
                self.arrivals.append((time.perf_counter(), sample.voltage_cmd_v))
                self.cond.notify_all()
        return sample


def _wait_applied(be: _TimedBackend, start_len: int, volts: float, timeout_s: float) -> float:
    deadline = time.perf_counter() + timeout_s
    with be.cond:
        i = start_len
        while True:
            while i < len(be.arrivals):
                if abs(be.arrivals[i][1] - volts) < 1e-4 + 1e-3:  # within one LSB
                    return be.arrivals[i][0]
                i += 1
            left = deadline - time.perf_counter()
            if left <= 0:
                return float("nan")
            be.cond.wait(left)


def _board_process(baud: int) -> tuple[subprocess.Popen[str], str]:
    """`pmdc-ident virtual-board` in its own process (as a real board has its own CPU)."""
    cmd = [sys.executable, "-m", "pmdc_ident.cli", "virtual-board", "--baud", str(baud)]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    assert proc.stdout is not None
    line = proc.stdout.readline()
    port = line.split(" on ", 1)[1].split()[0]
    return proc, port


def measure(baud: int, period_us: int, seconds: float, commands: int) -> dict[str, float]:
    motor = load_motor("seed000_ebike")
    proc, port = _board_process(baud)
    try:
        be = _TimedBackend(port, baud, motor.limits, period_us * 1e-6, logger=print)
        be.start()
        try:
            # Rate: stream with the motor driven at a small voltage.
            be.command_voltage(1.0)
            be.poll()
            t0 = time.perf_counter()
            n = 0
            while time.perf_counter() - t0 < seconds:
                n += len(be.poll())
                time.sleep(0.01)
            span = time.perf_counter() - t0
            n += len(be.poll())
            stats = be.link_stats
            # Latency: alternate 1.000 V / 1.001 V... at random phases of the grid.
            lat = []
            for k in range(commands):
                mv = 1000 + 10 * (k % 50) + 10  # LSB-distinct from the previous one
                with be.cond:
                    start_len = len(be.arrivals)
                t_send = time.perf_counter()
                try:
                    be.command_voltage(mv / 1000.0)
                    t_seen = _wait_applied(be, start_len, mv / 1000.0, 0.2)
                    lat.append(t_seen - t_send)
                    be.poll()
                except BackendError as exc:  # reported, then the backend reconnects
                    print(f"  link: {exc}")
                    time.sleep(0.5)
                time.sleep(0.003 + (k % 7) * period_us * 1e-6 / 7)
            rtt = be.link_stats.ping_rtt_s
        finally:
            be.close()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
    lat = sorted(x for x in lat if x == x)  # NaN: not seen within 0.2 s
    cmd_bytes = len(frame_message(SetVoltage(1000), 1))
    floor_s = (cmd_bytes + TELEMETRY_WIRE_BYTES) * 10 / baud + period_us * 1e-6 / 2
    return {
        "rate_hz": n / span,
        "requested_hz": 1e6 / period_us,
        "line_hz": baud / (TELEMETRY_WIRE_BYTES * 10),
        "dropped": stats.dropped_samples,
        "errors": stats.crc_errors + stats.framing_errors,
        "lat_med_ms": 1e3 * statistics.median(lat),
        "lat_p95_ms": 1e3 * lat[int(0.95 * (len(lat) - 1))],
        "lat_max_ms": 1e3 * lat[-1],
        "floor_ms": 1e3 * floor_s,
        "rtt_ms": 1e3 * rtt,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0)
    ap.add_argument("--commands", type=int, default=150)
    args = ap.parse_args()
    print(f"telemetry frame {TELEMETRY_WIRE_BYTES} bytes = {TELEMETRY_WIRE_BYTES * 10} bit times")
    head = (
        f"{'baud':>8} {'req Hz':>7} {'got Hz':>8} {'got/req':>7} {'line Hz':>8} "
        f"{'use':>5} {'drop':>5} {'err':>4} {'lat med':>8} {'p95':>6} {'max':>6} "
        f"{'floor':>6} {'med/flr':>7} {'ping':>6}"
    )
    print(head + "   (latencies in ms)")
    for baud in (115200, 1_000_000):
        fastest = max(min_period_us(baud), 250)
        periods = [fastest] + [p for p in (1000, 4000) if p > fastest]
        for period in periods:
            r = measure(baud, period, args.seconds, args.commands)
            print(
                f"{baud:>8} {r['requested_hz']:7.0f} {r['rate_hz']:8.1f} "
                f"{r['rate_hz'] / r['requested_hz']:7.3f} {r['line_hz']:8.0f} "
                f"{r['rate_hz'] / r['line_hz']:5.0%} {r['dropped']:>5} {r['errors']:>4} "
                f"{r['lat_med_ms']:8.3f} {r['lat_p95_ms']:6.3f} {r['lat_max_ms']:6.3f} "
                f"{r['floor_ms']:6.3f} {r['lat_med_ms'] / r['floor_ms']:7.2f} "
                f"{r['rtt_ms']:6.3f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
