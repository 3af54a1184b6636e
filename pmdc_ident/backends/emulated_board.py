"""The reference firmware on an emulated ATmega328P, against a simulated motor, on a pty.

:class:`EmulatedBoard` builds the sketch (``firmware/arduino/pmdc_board``) with the
Arduino AVR core for an Uno and the simavr rig around it (``firmware/emulator``:
``build.py`` caches both by content hash), then runs ``pmdc_emu``: the sketch
executes cycle by cycle at 16 MHz while a motor part in C drives its ADC and
encoder pins from the bridge pins, and its UART is bridged to a pseudo-terminal.
The host opens :attr:`EmulatedBoard.port` exactly as it opens the Python
:class:`~pmdc_ident.backends.virtual_board.VirtualBoard`'s, or a real board.

The emulator process ends with this one (it asks the kernel for a parent-death
signal and checks its parent itself), on :meth:`close`, and on SIGINT/SIGTERM.
Fault paths: :meth:`reset` (the AVR resets, as after a brown-out), :meth:`cut_line`
(the serial line is cut with the board powered), :meth:`pause`/:meth:`resume` (the
whole board freezes), :meth:`unplug` (the process ends: the pty disappears).

Needs Debian's ``gcc-avr avr-libc arduino-core-avr libsimavr-dev`` (``simavr``,
``libsimavrparts1``): :func:`tools_missing` names what is absent, in one line.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from pmdc_ident.backends.base import BackendError
from pmdc_ident.core.effects import CoulombFriction, LoadTorque
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.motors import MotorSpec, share_candidates

__all__ = [
    "DEFAULT_COUNTS_PER_REV",
    "EmulatedBoard",
    "EmulatorError",
    "build_firmware",
    "firmware_dir",
    "tools_missing",
]

DEFAULT_COUNTS_PER_REV = 2048  # PMDC_COUNTS_PER_REV of the sketch
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
    """In the emulator before exec: SCHED_RR where permitted, else a lower niceness.

    (A local copy of what nodes/priority.py does for the nodes: backends may not
    import the node layer.) Round-robin at a low real-time priority: the emulator
    sleeps whenever it is ahead of the wall clock, so it takes ~0.4 of a core."""
    try:
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(10))
    except (OSError, AttributeError):
        try:
            os.setpriority(os.PRIO_PROCESS, 0, -5)
        except OSError:
            pass


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
        priority: bool = True,
        stats_path: str | Path | None = None,
        extra_args: tuple[str, ...] = (),
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
        self.priority = priority  # SCHED_RR where permitted: a board has a CPU of its own
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
        self.proc = subprocess.Popen(
            self.command(),
            preexec_fn=_raise_priority if self.priority else None,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        deadline = time.monotonic() + timeout_s
        assert self.proc.stdout is not None
        while time.monotonic() < deadline:
            line = self.proc.stdout.readline()
            if line.startswith("pty "):
                self.port = line.split(None, 1)[1].strip()
                return self
            if not line and self.proc.poll() is not None:
                break
        err = self._stderr_tail()
        self.close()
        msg = f"emulated board did not start: {err or 'no pty within the timeout'}"
        raise EmulatorError(msg)

    def _stderr_tail(self) -> str:
        proc = self.proc
        if proc is None or proc.poll() is None or proc.stderr is None:
            return ""
        lines = [ln for ln in proc.stderr.read().splitlines() if ln.strip()]
        return lines[-1] if lines else f"exit status {proc.returncode}"

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
