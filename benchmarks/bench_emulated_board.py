"""The reference sketch on an emulated Uno: what it sustains, measured.

    nice .venv/bin/python benchmarks/bench_emulated_board.py [--long-s 60] [--quick]

1. rate x baud: the rig's scripted host (free-running, exact) streams at each period
   for 2 s of board time with 12 V steps every 50 ms: frames, dropped samples, CPU
   idle from cycle counts, the sample routine's longest run, command-to-PWM latency;
   and a period below the board's limit, which it must refuse;
2. the encoder limit: the shaft driven 0 -> 700 rad/s while streaming at 1 kHz; the
   edge rate of the first missed count;
3. the watchdog: the host falls silent while driving; armature open after ...;
4. the long run: the real host (SerialBackend) over the pty at 1 kHz / 1 Mbaud for
   --long-s seconds in real time: dropped samples, and the emulator's CPU time per
   simulated second (the naive reference: one simulated second per wall second).
Needs the Debian packages of .ci/run.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from pmdc_ident.backends.base import BackendError
from pmdc_ident.backends.emulated_board import EmulatedBoard, build_firmware, tools_missing
from pmdc_ident.backends.serial_board import SerialBackend
from pmdc_ident.core.motors import load_motor
from pmdc_ident.protocol import min_period_us

BAUDS = (115200, 250000, 500000, 1000000)


def scripted(elf: Path, emu: Path, baud: int, *args: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        stats = Path(tmp) / "s.json"
        cmd = [str(emu), "--firmware", str(elf), "--baud", str(baud), "--free-run"]
        subprocess.run([*cmd, "--stats", str(stats), *args], capture_output=True, check=True)
        return json.loads(stats.read_text())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--long-s", type=float, default=60.0)
    ap.add_argument("--quick", action="store_true", help="0.5 s per table cell")
    args = ap.parse_args()
    missing = tools_missing()
    if missing:
        print(f"bench_emulated_board: {missing}", file=sys.stderr)
        return 3
    dur = "0.5" if args.quick else "2"
    print("rate x baud (scripted host, 12 V steps every 50 ms, board time", dur, "s)")
    print(
        f"{'baud':>8} {'period us':>9} {'rate Hz':>8} {'frames':>7} {'dropped':>7} "
        f"{'idle %':>6} {'sample max us':>13} {'latency max us':>14}"
    )
    rigs = {}
    for baud in BAUDS:
        elf, emu = rigs[baud] = build_firmware(baud)
        board_min = max(min_period_us(baud), 1000)
        for period in sorted(
            {board_min, 1000, 2000, 4000} - {p for p in (1000, 2000) if p < board_min}
        ):
            s = scripted(
                elf, emu, baud, "--host", str(period), "--step", "12,0.05", "--duration", dur
            )
            h = s["host"]
            print(
                f"{baud:>8} {period:>9} {1e6 / period:>8.0f} {h['frames']:>7} {h['dropped']:>7} "
                f"{100 * s['cpu']['idle']:>6.1f} {s['sample_max_us']:>13.0f} "
                f"{s['latency_us']['max']:>14.0f}"
            )
        s = scripted(elf, emu, baud, "--host", str(board_min - 10), "--duration", "0.2")
        print(
            f"{baud:>8} {board_min - 10:>9}  refused: "
            f"{s['host']['errors'] == 1 and s['host']['frames'] == 0}"
        )
    elf, emu = rigs[1000000]
    s = scripted(elf, emu, 1000000, "--host", "1000", "--ramp", "700,3,0.2", "--duration", "3.3")
    e = s["encoder"]
    print(
        f"\nencoder ({e['counts_per_rev']} counts/rev, 1 kHz stream, shaft 0 -> 700 rad/s): "
        f"first missed count at {e['first_miss_edge_rate']:.0f} edges/s; "
        f"{e['missed']} missed of {e['edges']}"
    )
    s = scripted(elf, emu, 1000000, "--host", "1000", "--ramp", "300,2,0.2", "--duration", "2.5")
    e, h = s["encoder"], s["host"]
    print(
        f"encoder up to {e['max_edge_rate']:.0f} edges/s: {e['missed']} missed, "
        f"{h['dropped']} dropped samples (documented limit 100000 edges/s)"
    )
    s = scripted(
        elf,
        emu,
        1000000,
        "--host",
        "1000",
        "--step",
        "6,10",
        "--host-silent-at",
        "0.5",
        "--duration",
        "1.5",
    )
    print(
        f"watchdog: armature open {s['host']['open_after_last_frame_s'] * 1e3:.1f} ms after "
        f"the host's last frame (500 ms configured); ADC {s['adc']['conversion_us']:.0f} us a "
        f"conversion, {s['adc']['conversions'] / max(1, s['samples_pin']):.1f} a sample"
    )

    print(f"\nlong run: real host over the pty, 1 kHz at 1 Mbaud, {args.long_s:g} s")
    board = EmulatedBoard(load_motor("seed000_ebike"), baud=1000000).start()
    be = SerialBackend(board.port, 1000000, dt_s=0.001)
    be.start()
    n = 0
    losses: list[str] = []
    t0 = time.monotonic()
    while time.monotonic() - t0 < args.long_s:
        k = int((time.monotonic() - t0) / 0.5)
        try:
            be.command_voltage((6.0, 12.0, 18.0, 0.0)[k % 4])
        except BackendError:
            pass  # reconnecting: reported below
        try:
            n += len(be.poll())
        except BackendError as exc:
            losses.append(str(exc))
        time.sleep(0.01)
    st = be.link_stats
    be.close()
    board.close()
    es = board.stats() or {}
    board.cleanup()
    print(
        f"samples {n}, dropped {st.dropped_samples}, crc {st.crc_errors}, host-skipped "
        f"{be.skipped_samples}; emulator: "
        f"{es.get('cpu_s', 0) / max(1e-9, es.get('sim_s', 1)):.3f} "
        f"s CPU per simulated second (real time = 1.000), {es.get('stalled_s', 0):.2f} s stalled"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
