"""A session's processes end with it, its domain stays held until they do, and it reports
itself - never an older session (issue 28, items 2 and 4). Real processes, real signals.

* the recorder killed mid-session: ``bringup`` says ABORTED, names this session's bag
  as incomplete and exits non-zero (it printed the previous session's bag, parameters
  and diagnosis, exit 0): in ``test_identification_node.py``, on the session whose
  truncated bag is read there (``killed_recorder_run``);
* ``kill -9`` of ``bringup``: every node stops (it kept running for minutes) and the
  DDS domain stays locked until the last one is gone (it was released at once, and
  the next session ran a second driver on the same domain);
* SIGHUP (the terminal closed): forwarded like Ctrl-C, everything stops, no traceback.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
from helpers.paths import REPO
from helpers.plans import SHORT_SEQUENCE

from pmdc_ident.process.bringup import node_env

pytestmark = [pytest.mark.ros, pytest.mark.slow]
pytest.importorskip("rclpy")


def _bringup(tmp_path: Path, domain: int, *extra: str) -> subprocess.Popen[str]:
    """bringup on ``domain`` (held by this test, so no one else's DDS traffic is on it),
    taking its own lock in a private lock folder as a user's bringup takes it in /tmp."""
    cmd = [
        sys.executable,
        "-m",
        "pmdc_ident.process.bringup",
        "--motor",
        "seed001_110v",
        "--output-dir",
        str(tmp_path / "out"),
        "--domain-id",
        str(domain),
        "-p",
        "identification:safety.data_timeout_s=1.5",
        "-p",
        "driver:watchdog_s=1.5",
        *extra,
    ]
    for k, v in SHORT_SEQUENCE.items():
        cmd += ["-p", f"identification:{k}={v}"]
    env = node_env(domain)
    env.pop("PMDC_DDS_DOMAIN_HELD", None)  # bringup takes the lock itself, as a user's would
    env["PMDC_DDS_LOCK_DIR"] = str(_lock_dir(tmp_path))
    return subprocess.Popen(
        cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )


def _wait_for(proc: subprocess.Popen[str], text: str, lines: list[str], timeout_s=120.0) -> None:
    assert proc.stdout is not None
    deadline = time.monotonic() + timeout_s
    for line in proc.stdout:
        lines.append(line)
        if text in line or time.monotonic() > deadline:
            return
    raise AssertionError("".join(lines))


def _nodes(pid: int) -> list[psutil.Process]:
    return [p for p in psutil.Process(pid).children(recursive=True) if p.is_running()]


def _gone(procs: list[psutil.Process], timeout_s: float) -> list[psutil.Process]:
    _, alive = psutil.wait_procs(procs, timeout=timeout_s)
    return [p for p in alive if p.status() != psutil.STATUS_ZOMBIE]


def _lock_dir(tmp_path: Path) -> Path:
    d = tmp_path / "locks"
    d.mkdir(exist_ok=True)
    return d


def _busy(tmp_path: Path, domain: int) -> bool:
    """Another process (a second session) finds ``domain`` busy in bringup's lock folder."""
    probe = (
        "import sys\nfrom pmdc_ident.process.dds_domain import DomainBusyError, lock_domain\n"
        f"try:\n    lock_domain({domain})\nexcept DomainBusyError:\n    sys.exit(3)\n"
    )
    env = {**node_env(domain), "PMDC_DDS_LOCK_DIR": str(_lock_dir(tmp_path))}
    env.pop("PMDC_DDS_DOMAIN_HELD", None)
    return subprocess.run([sys.executable, "-c", probe], env=env, timeout=60).returncode == 3


def test_kill_9_of_bringup_stops_every_node_and_the_domain_stays_held_until_then(
    tmp_path, ros_domain
):
    proc = _bringup(tmp_path, ros_domain)
    lines: list[str] = []
    _wait_for(proc, "segments, nominal", lines)
    nodes = _nodes(proc.pid)
    assert len(nodes) >= 3, [p.cmdline() for p in nodes]
    assert _busy(tmp_path, ros_domain)
    proc.kill()
    proc.wait(timeout=10)
    # the nodes still winding down keep the domain: a second session is refused
    still = [p for p in nodes if p.is_running() and p.status() != psutil.STATUS_ZOMBIE]
    if still:
        assert _busy(tmp_path, ros_domain)
    alive = _gone(nodes, 20.0)
    assert not alive, [p.cmdline() for p in alive]
    assert not _busy(tmp_path, ros_domain)  # free once the last node is gone


def test_sighup_to_bringup_stops_everything_safe_without_a_traceback(tmp_path, ros_domain):
    proc = _bringup(tmp_path, ros_domain)
    lines: list[str] = []
    _wait_for(proc, "segments, nominal", lines)
    nodes = _nodes(proc.pid)
    time.sleep(1.0)
    proc.send_signal(signal.SIGHUP)
    rest, _ = proc.communicate(timeout=60)
    text = "".join(lines) + rest
    assert proc.returncode != 0, text
    assert "driver stopped: motor safe" in text, text
    assert "Traceback" not in text, text
    assert not _gone(nodes, 10.0)
