"""The DDS domain lock: no two processes on this machine hold one id (no DDS started here)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from pmdc_ident.process import dds_domain
from pmdc_ident.process.dds_domain import (
    HELD_ENV,
    POOL,
    DomainBusyError,
    allocate_domain,
    child_env,
    lock_domain,
)

_HOLD = r"""
import sys, time
from pmdc_ident.process.dds_domain import lock_domain
lock = lock_domain(int(sys.argv[1]), purpose="holder test")
print("held", flush=True)
time.sleep(60)
"""


@pytest.fixture
def lock_dir(tmp_path, monkeypatch) -> Path:
    monkeypatch.setenv("PMDC_DDS_LOCK_DIR", str(tmp_path))
    monkeypatch.delenv(HELD_ENV, raising=False)
    # the suite's own domains (the session default may be any id of the pool, 30 too)
    # are held in this process: the tests here start from none
    monkeypatch.setattr(dds_domain, "_held", {})
    return tmp_path


def _holder(domain: int) -> subprocess.Popen[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", _HOLD, str(domain)], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None and proc.stdout.readline().strip() == "held"
    return proc


def test_pool_avoids_the_demo_and_hand_picked_ids_and_stays_below_ephemeral_ports():
    assert 42 not in POOL and not set(range(11, 21)) & set(POOL) and 0 not in POOL
    assert 7400 + 250 * max(POOL) + 10 + 2 * 50 < 32768


def test_a_domain_held_by_another_process_is_busy_until_that_process_is_killed(lock_dir):
    holder = _holder(77)
    try:
        with pytest.raises(
            DomainBusyError, match=rf"ROS_DOMAIN_ID 77 is in use by pid {holder.pid}"
        ):
            lock_domain(77)
        with allocate_domain([76, 77]) as lock:  # the free one
            assert lock.domain_id == 76
    finally:
        holder.send_signal(signal.SIGKILL)  # the kernel drops the lock: never stale
        holder.wait()
    with lock_domain(77) as lock:
        assert lock.domain_id == 77


def test_nested_locks_in_one_process_and_allocation_never_hands_out_a_held_id(lock_dir):
    outer = lock_domain(30)
    inner = lock_domain(30)  # e.g. run_session inside a test holding the domain
    inner.release()
    assert 30 in dds_domain._held  # still held by the outer one
    with pytest.raises(DomainBusyError, match="every DDS domain id of 30..30 is in use"):
        allocate_domain([30])
    outer.release()
    assert 30 not in dds_domain._held
    with allocate_domain([30]) as lock:
        assert lock.domain_id == 30


def test_a_child_runs_under_its_parents_lock_and_only_for_that_domain(lock_dir):
    with lock_domain(31):
        env = {**os.environ, **child_env(31)}
        assert env[HELD_ENV] == "31" and child_env(32) == {}
        code = (
            "from pmdc_ident.process.dds_domain import lock_domain, DomainBusyError\n"
            "lock_domain(31).release()\n"
            "try:\n    lock_domain(32)\nexcept DomainBusyError:\n    raise SystemExit(3)\n"
        )
        proc = subprocess.run([sys.executable, "-c", code], env=env, check=False)
        assert proc.returncode == 0  # 31 through the parent; 32 is free
        del env[HELD_ENV]
        proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True)
        assert b"ROS_DOMAIN_ID 31 is in use" in proc.stderr


def test_bringup_on_a_busy_domain_is_one_line_and_exit_2(lock_dir):
    holder = _holder(33)
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "pmdc_ident.process.bringup", "--domain-id", "33"]
            + ["--output-dir", str(lock_dir / "out")],
            capture_output=True,
            text=True,
            timeout=60,
            check=False,
        )
    finally:
        holder.kill()
        holder.wait()
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip().splitlines() == [
        f"bringup: error: ROS_DOMAIN_ID 33 is in use by pid {holder.pid} (holder test) on "
        "this machine: choose another domain id (--domain-id)"
    ]
