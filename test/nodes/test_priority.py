"""A loop node raises its own priority when nothing above it chose one (``ros2 run``,
``ros2 launch``), keeps what its parent chose, and stays normal on request."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest
from helpers.paths import REPO

from pmdc_ident.process.bringup import node_env

_PROBE = """
import json, os
from pmdc_ident.process.priority import raise_own_priority
said = raise_own_priority()
print(json.dumps({"said": said, "policy": os.sched_getscheduler(0),
                  "nice": os.getpriority(os.PRIO_PROCESS, 0)}))
"""


def _rr_permitted() -> bool:
    probe = "import os; os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(10))"
    return subprocess.run([sys.executable, "-c", probe], check=False).returncode == 0


def _probe(env_extra: dict[str, str], preexec=None) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PMDC_IDENT_REALTIME"} | env_extra
    out = subprocess.run(
        [sys.executable, "-c", _PROBE],
        capture_output=True,
        text=True,
        env=env,
        timeout=120,
        check=True,
        preexec_fn=preexec,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_loop_node_started_plainly_raises_itself() -> None:
    res = _probe({})
    if _rr_permitted():
        assert res["policy"] == os.SCHED_RR
        assert res["said"] == "SCHED_RR priority 10"
    else:  # a plain account: nice -5 where permitted, else normal, never an error
        assert res["policy"] == os.SCHED_OTHER
        assert res["said"].startswith("nice ")


def test_what_the_parent_chose_is_kept() -> None:
    res = _probe({}, preexec=lambda: os.setpriority(os.PRIO_PROCESS, 0, 3))
    assert res["policy"] == os.SCHED_OTHER and res["nice"] == 3
    assert res["said"] == "nice 3"


def test_pmdc_ident_realtime_0_keeps_normal_scheduling() -> None:
    res = _probe({"PMDC_IDENT_REALTIME": "0"})
    assert res["policy"] == os.SCHED_OTHER and res["nice"] == 0
    assert "PMDC_IDENT_REALTIME=0" in res["said"]


@pytest.mark.skipif(not _rr_permitted(), reason="SCHED_RR not permitted here")
def test_the_driver_node_under_ros2_run_runs_at_the_loop_priority(ros_domain) -> None:
    # as ros2 run / ros2 launch start it: a plain child, no preexec from bringup
    env = node_env(domain_id=ros_domain)
    cmd = [sys.executable, "-m", "pmdc_ident.nodes.driver_node", "--ros-args"]
    cmd += ["--params-file", str(REPO / "config" / "driver.yaml")]
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 60.0
        while os.sched_getscheduler(proc.pid) != os.SCHED_RR:
            assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
            assert time.monotonic() < deadline, "the driver never raised its priority"
            time.sleep(0.05)
        assert os.sched_getparam(proc.pid).sched_priority == 10
    finally:
        proc.send_signal(2)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
