"""The reference sketch on an emulated Uno: what it sustains, measured.

    nice .venv/bin/python benchmarks/bench_emulated_board.py [--long-s 60] [--quick]
        [--no-session]

1. rate x baud: the rig's scripted host (free-running, exact) streams at each period
   for 2 s of board time with 12 V steps every 50 ms: frames, dropped samples, CPU
   idle from cycle counts, the sample routine's longest run, command-to-PWM latency;
   and a period below the board's limit, which it must refuse;
2. the encoder limit: the shaft driven 0 -> 700 rad/s while streaming at 1 kHz; the
   edge rate of the first missed count;
3. the watchdog: the host falls silent while driving; armature open after ...;
4. the long run: the real host (SerialBackend) over the pty at 1 kHz / 1 Mbaud for
   --long-s seconds in real time: dropped samples, when each count was latched and when
   the bridge took a new setpoint (after the sample instant), and the emulator's CPU
   time per simulated second (the naive reference: one simulated second per wall
   second) and how far it fell behind the wall clock;
5. a whole identification session (bringup: driver with backend serial, recorder,
   identification; the default sequence) over the emulated board at 1 kHz / 1 Mbaud,
   host stalls up to --stall-s tolerated: the bag, and the parameters against the motor
   part's truth.
Needs the Debian packages of .ci/run (and the ROS wheels of the .venv for 5).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from pmdc_ident.backends.base import BackendError
from pmdc_ident.backends.emulated_board import (
    EmulatedBoard,
    build_firmware,
    counts_for_motor,
    tools_missing,
)
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
    ap.add_argument("--no-session", action="store_true", help="skip the bringup session")
    ap.add_argument("--session-only", action="store_true", help="only the bringup session")
    ap.add_argument(
        "--stall-s",
        type=float,
        default=3.0,
        help="host stalls the session tolerates (driver watchdog_s, identification "
        "safety.data_timeout_s; the demo's 1.5 s is not always enough here)",
    )
    ap.add_argument(
        "--out", default="out/bench_emulated_session", help="the session's bag and logs"
    )
    args = ap.parse_args()
    missing = tools_missing()
    if missing:
        print(f"bench_emulated_board: {missing}", file=sys.stderr)
        return 3
    if args.session_only:
        session(Path(args.out), args.stall_s)
        return 0
    dur = "0.5" if args.quick else "2"
    print("rate x baud (scripted host, 12 V steps every 50 ms, board time", dur, "s)")
    print(
        f"{'baud':>8} {'period us':>9} {'rate Hz':>8} {'frames':>7} {'dropped':>7} "
        f"{'idle %':>6} {'sample max us':>13} {'latch after us':>14} {'bridge after us':>15}"
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
            h, tm = s["host"], s["timing"]
            cap, br = tm["capture_late_us"], tm["bridge_after_capture_us"]
            print(
                f"{baud:>8} {period:>9} {1e6 / period:>8.0f} {h['frames']:>7} {h['dropped']:>7} "
                f"{100 * s['cpu']['idle']:>6.1f} {s['sample_max_us']:>13.0f} "
                f"{cap['min']:>6.0f}..{cap['max']:<6.0f} {br['min']:>7.0f}..{br['max']:<6.0f}"
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

    long_run(args.long_s)
    if not args.no_session:
        session(Path(args.out), args.stall_s)
    return 0


def long_run(seconds: float) -> None:
    from pmdc_ident.process.priority import realtime_thread

    print(f"\nlong run: real host over the pty, 1 kHz at 1 Mbaud, {seconds:g} s")
    board = EmulatedBoard(load_motor("seed000_ebike"), baud=1000000).start()
    n = 0
    losses: list[str] = []
    # the host polls at a driver node's priority (its reader thread inherits it)
    with realtime_thread():
        be = SerialBackend(board.port, 1000000, dt_s=0.001)
        be.start()
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
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
    tm, rt = es.get("timing", {}), es.get("realtime", {})
    cap, br = tm.get("capture_late_us", {}), tm.get("bridge_after_capture_us", {})
    print(
        f"samples {n}, dropped {st.dropped_samples}, crc {st.crc_errors}, host-skipped "
        f"{be.skipped_samples}, link losses {len(losses)}, bytes the host did not take "
        f"{es.get('uart', {}).get('lost', 0)}"
    )
    print(
        f"counts latched {cap.get('min', 0):.0f}..{cap.get('max', 0):.0f} us after the "
        f"sample instant; bridge reprogrammed {br.get('min', 0):.0f}..{br.get('max', 0):.0f} "
        f"us after it (trips open it at once)"
    )
    print(
        f"emulator: {es.get('cpu_s', 0) / max(1e-9, es.get('sim_s', 1)):.3f} s CPU per "
        f"simulated second (real time = 1.000; {rt.get('sched', '?')}), at most "
        f"{rt.get('behind_max_s', 0):.3f} s behind the wall clock, "
        f"{es.get('stalled_s', 0):.2f} s stalled"
    )


def session(out: Path, stall_s: float) -> None:
    """One bringup session over the emulated board; the parameters against the truth."""
    from pmdc_ident.process.bringup import run_session
    from pmdc_ident.process.dds_domain import allocate_domain

    spec = load_motor("seed000_ebike")
    counts, why = counts_for_motor(spec)
    print(
        f"\nsession: bringup --backend serial over the emulated board, 1 kHz at 1 Mbaud, "
        f"default sequence, host stalls up to {stall_s:g} s tolerated, encoder {counts} "
        f"counts/rev{f' ({why})' if why else ''}"
    )
    out.mkdir(parents=True, exist_ok=True)
    board = EmulatedBoard(spec, baud=1000000, counts_per_rev=counts).start()
    link = out / "board"
    if link.is_symlink():
        link.unlink()
    os.symlink(board.port, link)
    lock = allocate_domain(purpose="bench_emulated_board session")
    try:
        res = run_session(
            output_dir=out,
            motor=spec.name,
            domain_id=lock.domain_id,
            driver_params={
                "backend": "serial",
                "port": str(link),
                "baud": 1000000,
                "rate_hz": 1000.0,
                "watchdog_s": stall_s,  # this shared machine's stalls
            },
            identification_params={"safety.data_timeout_s": stall_s},
            log_dir=out / "logs",
            quiet=True,
            timeout_s=300.0,
        )
    finally:
        lock.release()
        link.unlink()
        board.close()
    es = board.stats() or {}
    board.cleanup()
    rt = es.get("realtime", {})
    print(
        f"session took {res.wall_s:.1f} s, identification exit {res.identification_rc}; "
        f"bag {res.bag}; emulator {es.get('cpu_s', 0) / max(1e-9, es.get('sim_s', 1)):.3f} s "
        f"CPU per simulated second, at most {rt.get('behind_max_s', 0):.3f} s behind"
    )
    if res.result is None:
        print(f"no parameters: see {out / 'logs'}")
        return
    _against_truth(res.result, spec)


def _against_truth(result: dict[str, Any], spec: Any) -> None:
    p = spec.model.params
    tc = next((e.torque_nm for e in spec.model.effects if hasattr(e, "torque_nm")), None)
    truth = {
        "R": (p.R, "R"),
        "L": (p.L, "L"),
        "Ke": (p.Ke, "Ke"),
        "Kt": (p.Kt, "Kt (identified as Ke: Kt = Ke assumed)"),
        # Kt = Ke closes the (Kt, J, B) scale: the part's J, B, Tc show times Ke/Kt
        "J": (p.J * p.Ke / p.Kt, "J * Ke/Kt"),
        "B": (p.B * p.Ke / p.Kt, "B * Ke/Kt"),
        "coulomb_friction.torque_nm": (
            (tc or 0.0) * p.Ke / p.Kt,
            "Tc * Ke/Kt",
        ),
    }
    print(f"model {result.get('model')}")
    print(f"{'parameter':<28} {'identified':>12} {'truth':>12} {'error %':>8}  compared with")
    for name, (ref, what) in truth.items():
        got = (result.get("parameters") or {}).get(name, {}).get("value")
        if got is None:
            continue
        print(f"{name:<28} {got:>12.6g} {ref:>12.6g} {100 * (got / ref - 1):>+8.2f}  {what}")


if __name__ == "__main__":
    sys.exit(main())
