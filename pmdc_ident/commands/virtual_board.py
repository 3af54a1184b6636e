"""``pmdc-ident virtual-board``: the motor model behind the serial protocol on a pty.

Prints the port, then runs until Ctrl-C (or SIGTERM). Point the driver node at
it exactly as at hardware: ``backend:=serial port:=<printed path> baud:=<baud>``.
``kill -USR1 <pid>`` makes the board reset (as a brown-out or a watchdog reset
of the MCU would); stopping the process is the cable being pulled.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
from pathlib import Path
from types import FrameType

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
        "--protocol-version",
        type=int,
        default=None,
        help=argparse.SUPPRESS,  # testing: pretend to be another firmware version
    )


def _stop(_sig: int, _frame: FrameType | None) -> None:
    raise KeyboardInterrupt


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
        if link is not None:
            if link.is_symlink():
                link.unlink()
            os.symlink(board.port, link)
        info = board.core.info
        print(
            f"virtual board on {board.port} ({args.baud} baud, motor {spec.name}, "
            f"protocol v{info.protocol_version}, shortest period {info.min_period_us} us = "
            f"{1e6 / info.min_period_us:.0f} Hz)",
            flush=True,
        )
        if link is not None:
            print(f"linked as {link}", flush=True)
        print(
            f"driver: ros2 run pmdc_ident driver_node --ros-args -p backend:=serial "
            f"-p port:={link or board.port} -p baud:={args.baud} "
            f"-p rate_hz:={min(1000.0, 1e6 / info.min_period_us):.1f}  "
            f"(Ctrl-C to stop; kill -USR1 {os.getpid()} to reset the board)",
            flush=True,
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
        # Remove the link only if it is still ours (another board may have taken it),
        # and before closing: a board started next may reuse the pty's number.
        if link is not None and link.is_symlink() and os.readlink(link) == board.port:
            link.unlink()
        board.close()
