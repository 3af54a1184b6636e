"""The reference firmware on an emulated ATmega328P, against a simulated motor, on a pty.

:class:`EmulatedBoard` builds the sketch (``firmware/arduino/pmdc_board``) with the
Arduino AVR core for an Uno and the simavr rig around it (``firmware/emulator``:
``build.py`` caches both by content hash), then runs ``pmdc_emu``: the sketch
executes cycle by cycle at 16 MHz while a motor part in C drives its ADC and
encoder pins from the bridge pins, and its UART is bridged to a pseudo-terminal.
The host opens :attr:`EmulatedBoard.port` exactly as it opens the Python
:class:`~pmdc_ident.backends.virtual_board.VirtualBoard`'s, or a real board.

The emulator process ends with this one (it asks the kernel for a parent-death
signal and checks its parent itself), on :meth:`close`, and on SIGINT/SIGTERM. It
keeps the board's time against the wall clock with a bounded CPU reservation
(``cpu_share`` of a core, SCHED_DEADLINE where permitted; never a real-time priority
that a catching-up emulator could use to starve its host), and says so on its log
when it falls behind (the machine gives it too little CPU). Its messages go to
``log`` (default: stderr).
Fault paths: :meth:`reset` (the AVR resets, as after a brown-out), :meth:`cut_line`
(the serial line is cut with the board powered), :meth:`pause`/:meth:`resume` (the
whole board freezes), :meth:`unplug` (the process ends: the pty disappears).

Needs Debian's ``gcc-avr avr-libc arduino-core-avr libsimavr-dev`` (``simavr``,
``libsimavrparts1``): :func:`tools_missing` names what is absent, in one line.
"""

from __future__ import annotations

import collections
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any

from pmdc_ident.backends.base import BackendError
from pmdc_ident.core.effects import CoulombFriction, LoadTorque
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.motors import MotorSpec, share_candidates
from pmdc_ident.protocol import min_period_us

__all__ = [
    "CPU_SHARE",
    "DEFAULT_COUNTS_PER_REV",
    "EmulatedBoard",
    "EmulatorError",
    "board_min_period_us",
    "build_firmware",
    "counts_for_motor",
    "firmware_dir",
    "tools_missing",
]

DEFAULT_COUNTS_PER_REV = 2048  # PMDC_COUNTS_PER_REV of the sketch
HW_MIN_PERIOD_US = 1000  # HW_MIN_PERIOD_US of the sketch (its CPU's limit)
MAX_EDGE_RATE = 100_000  # MAX_EDGE_RATE of the sketch: quadrature edges/s it follows
# The emulator's CPU reservation (SCHED_DEADLINE, fraction of one core): it needs about
# 0.35 to keep a 1 kHz stream in real time, the rest is its margin to catch up after
# a stall. Bounded by the kernel: it can never take more, whatever it does.
CPU_SHARE = 0.6
APT_PACKAGES = "gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev"
_ARDUINO_CORE = Path("/usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h")
_SIMAVR_HEADER = Path("/usr/include/simavr/sim_avr.h")


class EmulatorError(BackendError):
    """The emulated board cannot be built or started (one line)."""


def firmware_dir() -> Path | None:
    """The ``firmware/`` folder (source tree or an installed share/pmdc_ident/)."""
    return next(
        (c for c in share_candidates("firmware") if (c / "emulator" / "build.py").is_file()), None
    )


def tools_missing() -> str | None:
    """What is missing to build and run the emulated board, or None."""
    missing = [t for t in ("avr-gcc", "avr-g++", "gcc") if shutil.which(t) is None]
    if not _ARDUINO_CORE.is_file():
        missing.append("the Arduino AVR core")
    if not _SIMAVR_HEADER.is_file():
        missing.append("libsimavr-dev")
    if not missing:
        return None
    return f"{', '.join(missing)} not installed (apt-get install {APT_PACKAGES})"


def board_min_period_us(baud: int) -> int:
    """The shortest period the sketch accepts at ``baud`` (the line's or its CPU's)."""
    return max(min_period_us(int(baud)), HW_MIN_PERIOD_US)


def counts_for_motor(spec: MotorSpec) -> tuple[int, str]:
    """Encoder counts per turn for this motor on the emulated Uno, and why, in words.

    The motor file's encoder (else the sketch's default), halved until the motor's
    speed limit stays within the edges the sketch's interrupt follows: beyond them it
    trips OVER_SPEED, as it must on a real Uno with that encoder. ``why`` is empty
    when the file's encoder fits."""
    wanted = int(spec.sensors.encoder_counts_per_rev) or DEFAULT_COUNTS_PER_REV
    speed = spec.limits.speed_max_rad_s
    cpr = wanted
    while cpr > 64 and speed * cpr / (2.0 * math.pi) > MAX_EDGE_RATE:
        cpr //= 2
    if cpr == wanted:
        return cpr, ""
    need = speed * wanted / (2.0 * math.pi)
    return cpr, (
        f"the motor file's {wanted} would need {need:,.0f} edges/s at its "
        f"{speed:g} rad/s limit; the sketch follows {MAX_EDGE_RATE:,}"
    )


def build_firmware(baud: int, counts_per_rev: int = 0) -> tuple[Path, Path]:
    """(sketch ELF, emulator) for this baud, built or taken from the cache."""
    fw = firmware_dir()
    if fw is None:
        msg = "firmware sources not found (firmware/emulator/build.py)"
        raise EmulatorError(msg)
    missing = tools_missing()
    if missing is not None:
        msg = f"cannot build the emulated board: {missing}"
        raise EmulatorError(msg)
    cmd = [sys.executable, str(fw / "emulator" / "build.py"), "--baud", str(int(baud)), "--json"]
    if counts_per_rev:
        cmd += ["--counts-per-rev", str(int(counts_per_rev))]
    r = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=600)
    if r.returncode != 0:
        lines = (r.stderr or r.stdout).strip().splitlines() or ["no output"]
        detail = next((ln for ln in lines if "error" in ln.lower() and ln is not lines[0]), "")
        first = lines[0].removeprefix("build.py: ")
        raise EmulatorError(f"{first} {detail.strip()}".strip())
    paths = json.loads(r.stdout.strip().splitlines()[-1])
    return Path(paths["elf"]), Path(paths["emulator"])


def motor_arguments(spec: MotorSpec) -> str:
    """``--motor R,L,Ke,Kt,J,B,Tc,Tload`` for the C motor part (its equations only)."""
    p = spec.model.params
    tc = tload = 0.0
    for effect in spec.model.effects:
        if isinstance(effect, CoulombFriction):
            tc = float(effect.torque_nm)
        elif isinstance(effect, LoadTorque):
            tload = float(effect.torque_nm)
        else:
            name = getattr(effect, "NAME", type(effect).__name__)
            msg = (
                f"motor {spec.name}: the emulated board's motor part models R, L, Ke, Kt, J, B, "
                f"Coulomb friction and a load torque, not {name}"
            )
            raise ParameterError(msg)
    values = (p.R, p.L, p.Ke, p.Kt, p.J, p.B, tc, tload)
    if not all(math.isfinite(v) for v in values):
        msg = f"motor {spec.name}: parameters must be finite"
        raise ParameterError(msg)
    return ",".join(f"{v:.9g}" for v in values)


def _raise_priority() -> None:
    """In the emulator before exec: a lower niceness where permitted.

    (A local copy of what process/priority.py does for the nodes: backends may not
    import the node layer.) The emulator then asks for its CPU reservation itself
    (``--cpu-share``, SCHED_DEADLINE); this niceness is what it keeps where that is
    refused. Never a real-time priority: a catching-up emulator would take a whole
    core from the host it serves."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, -10)
    except OSError:
        pass


def _to_stderr(text: str) -> None:
    print(f"emulated board: {text}", file=sys.stderr, flush=True)


class EmulatedBoard:
    """The sketch on simavr with the motor part; run it with :meth:`start`."""

    def __init__(
        self,
        motor: MotorSpec,
        *,
        baud: int = 115200,
        supply_v: float | None = None,
        seed: int = 0,
        counts_per_rev: int = DEFAULT_COUNTS_PER_REV,
        current_noise_a: float | None = None,
        realtime: bool = True,
        cpu_share: float = CPU_SHARE,
        stats_path: str | Path | None = None,
        extra_args: tuple[str, ...] = (),
        log: Callable[[str], None] | None = None,
    ) -> None:
        if not 1200 <= int(baud) <= 2_000_000:
            msg = f"baud must be within 1200..2000000, got {baud}"
            raise ParameterError(msg)
        self.motor = motor
        self.baud = int(baud)
        self.supply_v = float(supply_v if supply_v is not None else 24.0)
        self.seed = int(seed)
        self.counts_per_rev = int(counts_per_rev)
        noise = motor.sensors.current_noise_a if current_noise_a is None else current_noise_a
        self.current_noise_a = float(noise)
        self.realtime = realtime
        if not (cpu_share == 0.0 or 0.05 <= cpu_share <= 0.95):
            msg = f"cpu_share must be 0 (none) or within 0.05..0.95 of a core, got {cpu_share}"
            raise ParameterError(msg)
        # A board has a CPU of its own: the emulator gets a bounded reservation where the
        # system permits it (0: it runs as a normal process).
        self.cpu_share = float(cpu_share)
        self.log = log if log is not None else _to_stderr
        self._stderr_lines: collections.deque[str] = collections.deque(maxlen=20)
        self._readers: list[threading.Thread] = []
        self._pty_line = threading.Event()
        self._own_stats = stats_path is None
        self.stats_path = Path(stats_path) if stats_path is not None else None
        self.extra_args = tuple(extra_args)
        self._motor_arg = motor_arguments(motor)
        self.port = ""
        self.proc: subprocess.Popen[str] | None = None
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self.elf: Path | None = None
        self.emulator: Path | None = None

    # -- lifecycle ---------------------------------------------------------------------
    def command(self) -> list[str]:
        """The emulator's command line (after :meth:`build`)."""
        assert self.elf is not None and self.emulator is not None
        cmd = [str(self.emulator), "--firmware", str(self.elf), "--motor", self._motor_arg]
        cmd += ["--supply", f"{self.supply_v:g}", "--baud", str(self.baud)]
        cmd += ["--counts-per-rev", str(self.counts_per_rev), "--seed", str(self.seed)]
        cmd += ["--current-noise", f"{self.current_noise_a:g}", "--parent", str(os.getpid())]
        if not self.realtime:
            cmd.append("--free-run")
        if self.cpu_share > 0:
            cmd += ["--cpu-share", f"{self.cpu_share:g}"]
        if self.stats_path is not None:
            cmd += ["--stats", str(self.stats_path)]
        return [*cmd, *self.extra_args]

    def build(self) -> EmulatedBoard:
        self.elf, self.emulator = build_firmware(self.baud, self.counts_per_rev)
        return self

    def start(self, timeout_s: float = 30.0) -> EmulatedBoard:
        """Build if needed, start the emulator, wait for its pty (returns self)."""
        if self.elf is None:
            self.build()
        if self._own_stats:
            self._tmp = tempfile.TemporaryDirectory(prefix="pmdc_emu_")
            self.stats_path = Path(self._tmp.name) / "stats.json"
        self._pty_line.clear()
        self._stderr_lines.clear()
        self.proc = subprocess.Popen(
            self.command(),
            preexec_fn=_raise_priority if self.cpu_share > 0 else None,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        # Both pipes are read to the end (a full pipe would stop the emulator): stdout
        # for the pty's name, stderr line by line to the log.
        assert self.proc.stdout is not None and self.proc.stderr is not None
        self._readers = [
            threading.Thread(target=self._read_stdout, args=(self.proc.stdout,), daemon=True),
            threading.Thread(target=self._read_stderr, args=(self.proc.stderr,), daemon=True),
        ]
        for t in self._readers:
            t.start()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and self.proc.poll() is None:
            if self._pty_line.wait(0.05):
                return self
        if self._pty_line.is_set():
            return self
        err = self._stderr_tail()
        self.close()
        msg = f"emulated board did not start: {err or 'no pty within the timeout'}"
        raise EmulatorError(msg)

    def _read_stdout(self, stream: IO[str]) -> None:
        for line in stream:
            if line.startswith("pty ") and not self._pty_line.is_set():
                self.port = line.split(None, 1)[1].strip()
                self._pty_line.set()

    def _read_stderr(self, stream: IO[str]) -> None:
        for line in stream:
            text = line.rstrip()
            if text:
                self._stderr_lines.append(text)
                if self._pty_line.is_set():  # start-up errors go into the exception
                    self.log(text.removeprefix("pmdc_emu: "))

    def _stderr_tail(self) -> str:
        proc = self.proc
        if proc is None:
            return ""
        try:
            proc.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            return ""
        for t in self._readers:
            t.join(timeout=2.0)
        return self._stderr_lines[-1] if self._stderr_lines else f"exit status {proc.returncode}"

    @property
    def stderr_lines(self) -> list[str]:
        """The emulator's last messages (AVR reset, line cut, behind real time, ...)."""
        return list(self._stderr_lines)

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def _signal(self, sig: int) -> None:
        if self.running:
            assert self.proc is not None
            self.proc.send_signal(sig)

    def reset(self) -> None:
        """The AVR resets (BOOT frame, armature open, new handshake); the rotor keeps turning."""
        self._signal(signal.SIGUSR1)

    def cut_line(self) -> None:
        """Cut (or reconnect) the serial line with the board powered: its watchdog fires."""
        self._signal(signal.SIGUSR2)

    def pause(self) -> None:
        """Freeze the whole board (its clock included)."""
        self._signal(signal.SIGSTOP)

    def resume(self) -> None:
        self._signal(signal.SIGCONT)

    def unplug(self) -> None:
        """Cable pulled: the emulator ends and its pty disappears."""
        self.close()

    def close(self, timeout_s: float = 5.0) -> int | None:
        """Stop the emulator (SIGTERM, then SIGKILL); returns its exit status."""
        proc = self.proc
        if proc is None:
            return None
        if proc.poll() is None:
            proc.send_signal(signal.SIGCONT)  # a paused board must see the SIGTERM
            proc.terminate()
            try:
                proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=timeout_s)
        for t in self._readers:  # the pipes end with the process
            t.join(timeout=timeout_s)
        self._readers = []
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                stream.close()
        return proc.returncode

    def stats(self) -> dict[str, Any] | None:
        """The emulator's measurements (written when it ends)."""
        if self.stats_path is None or not self.stats_path.is_file():
            return None
        return json.loads(self.stats_path.read_text())

    def cleanup(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> EmulatedBoard:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
        self.cleanup()
