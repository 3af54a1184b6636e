"""``pmdc-ident virtual-board``: the motor model behind the serial protocol on a pty.

Prints the port, then runs until Ctrl-C (or SIGTERM). Point the driver node at
it exactly as at hardware: ``backend:=serial port:=<printed path> baud:=<baud>``.
``kill -USR1 <pid>`` makes the board reset (as a brown-out or a watchdog reset
of the MCU would); stopping the process is the cable being pulled.

``--emulated`` runs the reference firmware itself instead of the Python board:
the sketch built for an Uno at ``--baud`` executes on simavr's ATmega328P against
the motor part of ``firmware/emulator`` (built on first use, then cached).
``kill -USR2 <pid>`` then cuts or reconnects its serial line with the board powered.
Its encoder has the motor file's counts per turn, halved until the motor's speed
limit fits the edges the sketch follows (``--counts-per-rev`` overrides), and the
emulator keeps the board's time with a bounded CPU reservation (``--cpu-share``).
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time
from pathlib import Path
from types import FrameType
from typing import Any

from pmdc_ident.core.enums import ExitCode
from pmdc_ident.core.errors import ParameterError

HELP = "run a simulated motor driver board on a pseudo-terminal (serial protocol v1)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--motor", default="seed000_ebike", help="built-in motor name or motor YAML path"
    )
    parser.add_argument(
        "--baud",
        type=int,
        default=115200,
        help="line rate the board paces its bytes to (a pty does not enforce one)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the current-sensor noise")
    parser.add_argument(
        "--supply-v", type=float, default=None, help="bridge supply, V (default: motor limit)"
    )
    parser.add_argument(
        "--link",
        type=Path,
        default=None,
        metavar="PATH",
        help="also make PATH a symlink to the pty (a stable name for launch files)",
    )
    parser.add_argument(
        "--nice",
        type=int,
        default=-10,
        help="scheduling niceness to ask for (a real board has a CPU of its own; "
        "ignored where not permitted)",
    )
    parser.add_argument(
        "--emulated",
        action="store_true",
        help="run the reference firmware on an emulated ATmega328P (simavr) instead",
    )
    parser.add_argument(
        "--counts-per-rev",
        type=int,
        default=0,
        help="--emulated: encoder counts per turn the sketch is built for (0: the motor "
        "file's, halved until its speed limit stays within the edges the sketch follows)",
    )
    parser.add_argument(
        "--cpu-share",
        type=float,
        default=None,
        help="--emulated: fraction of a core reserved for the emulator where permitted "
        "(SCHED_DEADLINE: always served, never more; 0 = none; default: a 1 kHz stream's "
        "need and a margin to catch up)",
    )
    parser.add_argument(
        "--protocol-version",
        type=int,
        default=None,
        help=argparse.SUPPRESS,  # testing: pretend to be another firmware version
    )


def _stop(_sig: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt


def _link(link: Path | None, port: str) -> None:
    if link is not None:
        if link.is_symlink():
            link.unlink()
        os.symlink(port, link)


def _unlink(link: Path | None, port: str) -> None:
    """Remove the link only if it is still ours (another board may have taken it), and
    before closing: a board started next may reuse the pty's number."""
    if link is not None and link.is_symlink() and os.readlink(link) == port:
        link.unlink()


def _announce(port: str, link: Path | None, baud: int, what: str, min_us: int, keys: str) -> None:
    """The board's port, its link, and the driver's command line to reach it."""
    print(
        f"virtual board on {port} ({baud} baud, {what}, shortest period {min_us} us = "
        f"{1e6 / min_us:.0f} Hz)",
        flush=True,
    )
    if link is not None:
        print(f"linked as {link}", flush=True)
    print(
        f"driver: ros2 run pmdc_ident driver_node --ros-args -p backend:=serial "
        f"-p port:={link or port} -p baud:={baud} -p rate_hz:={min(1000.0, 1e6 / min_us):.1f}"
        f"  (Ctrl-C to stop; {keys})",
        flush=True,
    )


def _check_link(link: Path | None) -> None:
    """``--link`` may replace a stale symlink, never a file or a folder."""
    if link is None:
        return
    if link.is_symlink():
        return
    if link.exists():
        kind = "folder" if link.is_dir() else "file"
        msg = f"--link {link}: a {kind} exists there; --link only replaces a symlink"
        raise ParameterError(msg)
    if not link.parent.is_dir():
        msg = f"--link {link}: folder {link.parent} does not exist"
        raise ParameterError(msg)


def run(args: argparse.Namespace) -> int:
    from pmdc_ident.backends.virtual_board import VirtualBoard
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.protocol import PROTOCOL_VERSION

    spec = load_motor(args.motor)
    if args.supply_v is not None and not args.supply_v > 0:
        msg = f"--supply-v must be > 0 V, got {args.supply_v}"
        raise ParameterError(msg)
    if args.seed < 0:
        msg = f"--seed must be >= 0, got {args.seed}"
        raise ParameterError(msg)
    _check_link(args.link)
    if args.emulated:
        return _run_emulated(args, spec)
    if args.cpu_share is not None or args.counts_per_rev:
        msg = "--cpu-share and --counts-per-rev are for the emulated board (--emulated)"
        raise ParameterError(msg)
    board = VirtualBoard(
        spec,
        baud=args.baud,
        supply_v=args.supply_v,
        seed=args.seed,
        protocol_version=args.protocol_version or PROTOCOL_VERSION,
    )
    link: Path | None = args.link
    try:
        os.setpriority(os.PRIO_PROCESS, 0, args.nice)
    except (OSError, ValueError):
        pass  # not permitted: run at the normal priority
    try:
        _link(link, board.port)
        info = board.core.info
        _announce(
            board.port,
            link,
            args.baud,
            f"motor {spec.name}, protocol v{info.protocol_version}",
            info.min_period_us,
            f"kill -USR1 {os.getpid()} to reset the board",
        )
        # Stop on Ctrl-C and SIGTERM even when started in the background by a
        # shell (which would leave SIGINT ignored).
        signal.signal(signal.SIGINT, _stop)
        signal.signal(signal.SIGTERM, _stop)
        # kill -USR1 <pid>: the MCU resets (BOOT frame, armature open, new handshake).
        signal.signal(signal.SIGUSR1, lambda _sig, _frame: board.reset())
        try:
            board.run_forever()
        except KeyboardInterrupt:
            pass
        print(
            f"virtual board stopped ({board.frames_sent} frames sent, "
            f"{board.samples_skipped} sample instants skipped while this process was starved)",
            file=sys.stderr,
        )
        return 0
    finally:
        _unlink(link, board.port)
        board.close()


def _run_emulated(args: argparse.Namespace, spec: Any) -> int:
    """The reference sketch on simavr (see the module docstring)."""
    from pmdc_ident.backends.emulated_board import (
        CPU_SHARE,
        EmulatedBoard,
        board_min_period_us,
        counts_for_motor,
    )

    if args.protocol_version:
        msg = "--protocol-version is for the Python board only"
        raise ParameterError(msg)
    if args.counts_per_rev < 0:
        msg = f"--counts-per-rev must be >= 0, got {args.counts_per_rev}"
        raise ParameterError(msg)
    counts, why = (args.counts_per_rev, "") if args.counts_per_rev else counts_for_motor(spec)
    try:
        os.setpriority(os.PRIO_PROCESS, 0, args.nice)  # the emulator inherits it
    except (OSError, ValueError):
        pass
    board = EmulatedBoard(
        spec,
        baud=args.baud,
        supply_v=args.supply_v,
        seed=args.seed,
        counts_per_rev=counts,
        cpu_share=CPU_SHARE if args.cpu_share is None else args.cpu_share,
    )
    link: Path | None = args.link
    stop = {"now": False}

    def _ask_stop(_sig: int, _frame: FrameType | None) -> None:
        stop["now"] = True

    signal.signal(signal.SIGINT, _ask_stop)
    signal.signal(signal.SIGTERM, _ask_stop)
    signal.signal(signal.SIGUSR1, lambda _s, _f: board.reset())
    signal.signal(signal.SIGUSR2, lambda _s, _f: board.cut_line())
    try:
        board.start()
        _link(link, board.port)
        _announce(
            board.port,
            link,
            args.baud,
            f"motor {spec.name}, emulated ATmega328P running {board.elf}, encoder "
            f"{counts} counts/rev{f' ({why})' if why else ''}",
            board_min_period_us(args.baud),
            f"kill -USR1 {os.getpid()} resets the AVR, kill -USR2 cuts the serial line",
        )
        while not stop["now"] and board.running:
            time.sleep(0.05)
        crashed = not board.running and not stop["now"]
        status = board.close()
        stats = board.stats() or {}
        if crashed:
            print(f"emulated board ended unexpectedly (exit status {status})", file=sys.stderr)
            return ExitCode.FAILED
        rt = stats.get("realtime", {})
        print(
            f"emulated board stopped ({stats.get('sim_s', 0.0):.1f} s of board time, "
            f"{stats.get('cpu_s', 0.0):.1f} s of emulator CPU ({rt.get('sched', '?')}), "
            f"at most {rt.get('behind_max_s', 0.0):.3f} s behind real time, "
            f"{stats.get('stalled_s', 0.0):.2f} s lost while it was paused or starved)",
            file=sys.stderr,
        )
        return 0
    finally:
        _unlink(link, board.port)
        board.close()
        board.cleanup()
