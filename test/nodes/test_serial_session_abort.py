"""A whole identification session over the serial backend, with the board pulled mid-run.

`pmdc-ident virtual-board` runs in its own process; `bringup` starts the
driver (backend serial), recorder and identification nodes. Once the session
records, the board process is killed (its pty disappears, as when a USB cable
is pulled). Expected: the driver reports it in one line and stays up, the
identification aborts the session cleanly with the motor safe, nothing crashes
and everything exits.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from pmdc_ident.process.bringup import node_env, priority_setter

pytestmark = [pytest.mark.ros, pytest.mark.slow, pytest.mark.timeout(150)]


def _wait_for(cond: Callable[[], bool], timeout_s: float) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.1)
    return cond()


def test_unplugging_the_board_mid_session_aborts_cleanly_with_the_motor_safe(
    tmp_path: Path, ros_domain: int
) -> None:
    link = tmp_path / "board"
    env = node_env(ros_domain)
    board = subprocess.Popen(
        [sys.executable, "-m", "pmdc_ident.cli", "virtual-board", "--baud", "1000000"]
        + ["--link", str(link)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        preexec_fn=priority_setter(-5, realtime=True),  # hardware is never held up
    )
    lines: list[str] = []
    session = None
    try:
        assert _wait_for(link.exists, 30.0), "virtual board did not come up"
        session = subprocess.Popen(
            [sys.executable, "-m", "pmdc_ident.process.bringup", "--backend", "serial"]
            + ["--port", str(link), "--domain-id", str(ros_domain)]
            + ["--output-dir", str(tmp_path / "bags"), "--timeout", "100"]
            + ["-p", "driver:baud=1000000", "-p", "driver:rate_hz=500.0"]
            # the abort (no driver sample) and the unconfirmable safe state (the board is
            # gone) each come 1.5 s after their cause, as in test_session_lifetimes, not 3 s
            + ["-p", "identification:safety.data_timeout_s=1.5"]
            + ["-p", "identification:confirm_timeout_s=1.5"],
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        assert session.stdout is not None
        reader = threading.Thread(target=lambda: lines.extend(session.stdout), daemon=True)
        reader.start()
        recording = _wait_for(lambda: any("recording session" in ln for ln in lines), 60.0)
        assert recording, "".join(lines[-30:])
        time.sleep(1.5)
        board.send_signal(signal.SIGTERM)  # the pty disappears: a pulled cable
        board.wait(timeout=10)
        rc = session.wait(timeout=80)
        reader.join(timeout=5)
    finally:
        for p in (session, board):
            if p is not None and p.poll() is None:
                p.kill()
    text = "".join(lines)
    unplug = [ln for ln in lines if "driver_node" in ln and "board unplugged?" in ln]
    assert len(unplug) == 1, text[-3000:]
    assert "motor commanded safe" in unplug[0]
    assert "ABORTED" in text, text[-3000:]
    assert "driver stopped: motor safe" in text, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    assert rc not in (0, None) and rc > 0  # no parameters, but a clean exit status
