"""The drift monitor node over real DDS: a heating simulated motor, flagged on /diagnostics.

Driver (sim backend, seed-000 motor with a strong resistance_drift) and monitor
node each in their own process; the test commands voltage steps and listens to
``model_drift``, ``/diagnostics`` and the latched ``reidentify_suggested``.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.paths import REPO

pytestmark = [pytest.mark.ros, pytest.mark.slow]

rclpy = pytest.importorskip("rclpy")

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from helpers.driver_harness import (  # noqa: E402
    DriverClient,
    DriverProcess,
    apply_ros_env,
)
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float64MultiArray, String  # noqa: E402

from pmdc_ident.core.stream_join import StampJoiner  # noqa: E402

K_HEAT = 0.002  # 1/(A^2 s): R rises fast enough to cross +20 % within seconds


class MonitorProcess(DriverProcess):
    """The monitor node as a child process (same lifecycle as the driver's)."""

    def start(self) -> MonitorProcess:
        cmd = [sys.executable, "-m", "pmdc_ident.nodes.monitor_node", "--ros-args"]
        for name, value in self.params.items():
            cmd += ["-p", f"{name}:={value}"]
        self.proc = subprocess.Popen(
            cmd, env=self.env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        return self


@pytest.fixture(scope="module")
def session(tmp_path_factory, module_ros_domain):
    motor = yaml.safe_load((REPO / "config" / "motors" / "seed000_ebike.yaml").read_text())
    motor["effects"]["resistance_drift"] = {"coeff_per_a2s": K_HEAT}
    path = tmp_path_factory.mktemp("monitor") / "heating.yaml"
    path.write_text(yaml.safe_dump(motor))
    domain = module_ros_domain
    apply_ros_env(domain)
    # The driver stops without waiting for this client's command publisher to go
    # (stop_wait_s: it would hold 0 V for 6 s); the monitor reports on /diagnostics
    # twice a second and calls 1 s without samples stale (the defaults, 1 s and 2 s,
    # cost the last test 1.5 s more wall time for the same check).
    with (
        DriverProcess(
            {"motor": str(path), "watchdog_s": 0.5, "stop_wait_s": 0.2}, domain_id=domain
        ) as driver,
        MonitorProcess(
            {"params": "seed000_ebike", "diagnostics_period_s": 0.5, "stale_s": 1.0},
            domain_id=domain,
        ) as monitor,
    ):
        rclpy.init()
        client = DriverClient(1000.0, name="test_monitor_client")
        got: dict[str, list] = {"drift": [], "diag": [], "suggest": [], "typed": []}
        client.create_subscription(
            String, "model_drift", lambda m: got["drift"].append(json.loads(m.data)), 100
        )
        client.create_subscription(
            Float64MultiArray, "model_drift/resistance", got["typed"].append, 100
        )
        client.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: got["diag"].extend(s for s in m.status if "motor drift" in s.name),
            100,
        )
        latched = QoSProfile(
            depth=1,
            reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL,
        )
        client.create_subscription(
            String,
            "reidentify_suggested",
            lambda m: got["suggest"].append(json.loads(m.data)),
            latched,
        )
        try:
            client.wait_for_driver(timeout_s=30.0, alive=driver.alive)
            # Hard steps heat the winding for 5 s, then gentle ones (little current,
            # so R nearly stops rising) keep the motor excited while the monitor catches up.
            hard, gentle = [14.0, -18.0, 18.0, -14.0], [2.0, 5.0, -3.0, 4.0, -5.0]
            stamps = client.encoder.stamps_ns
            start = stamps[-1]

            def step() -> None:
                # the motor's time, not the wall's: on a busy host the simulated driver
                # runs slower than real time, and 5 s of wall time heated it too little
                # to reach ERROR once (load 15)
                t = (stamps[-1] - start) * 1e-9
                levels = hard if t < 5.0 else gentle
                client.send(levels[int(t / 0.7) % len(levels)])

            # until the monitor has reported for 12 s of samples (it may start late) and
            # has said ERROR on every output the tests read: a level rises only once
            # proven twice, hold_s apart, and a monitor started late on a loaded machine
            # (its kernels compiled on a fresh clone) got there after those 12 s, and at
            # load 21 after more than 90 s. ERROR comes after 1-7 s of reports, but the
            # estimate then still lags the heated R by 10 % (an estimate 10 % too high
            # passed the first test's bound r_true * 1.02 there); after 12 s, by 1-4 %
            # (it converges no faster with the gentle levels switched every 0.2 s).
            end = time.monotonic() + 180.0
            while time.monotonic() < end and not _reported_error(got):
                client.spin_for(0.5, 0.02, step)
            client.catch_up()
            yield client, got, monitor, driver
        finally:
            client.destroy_node()
            rclpy.try_shutdown()


def _reported_error(got: dict[str, list]) -> bool:
    """12 s of reports, the last one's resistance at ERROR on ``model_drift``, its typed
    topic and ``/diagnostics``, and the re-identify suggestion latched."""
    drift = got["drift"]
    return (
        len(drift) >= 2
        and drift[-1]["t_s"] - drift[0]["t_s"] >= 12.0
        and drift[-1]["quantities"]["resistance"]["level"] == "ERROR"
        and bool(got["typed"])
        and list(got["typed"][-1].data)[-1] == 2.0
        and bool(got["diag"])
        and got["diag"][-1].level == b"\x02"
        and bool(got["suggest"])
        and got["suggest"][-1]["suggest_reidentify"] is True
    )


def test_heating_is_tracked_and_reported_over_dds(session):
    client, got, monitor, _ = session
    assert monitor.alive(), monitor.stderr
    assert got["drift"], "no model_drift message"
    last = got["drift"][-1]
    r = last["quantities"]["resistance"]
    assert r["unit"] == "ohm" and r["ci95"] > 0 and r["level"] == "ERROR"
    assert last["temperature_rise_k"] > 50.0
    joiner = StampJoiner(hold_s=0.0)
    for name, rec, col in (
        ("current", client.current, 0),
        ("speed", client.encoder, 1),
        ("voltage", client.voltage, 0),
    ):
        for ns, values in zip(rec.stamps_ns, rec.values, strict=True):
            joiner.add(name, ns, values[col])
    t, _, i, _ = joiner.take()
    keep = t <= last["t_s"] + 1e-6
    # Against the truth R0 (1 + k int i^2 dt): this heating (+60 % in 5 s) is far faster
    # than a winding's, so the estimate still lags it here (bench_monitor.py measures
    # tracking at thermal rates).
    heat = np.sum(i[keep] ** 2) * 1e-3
    r_true = 1.375 * (1 + K_HEAT * heat)
    assert 1.375 * 1.2 < r["value"] < r_true * 1.02


def test_diagnostics_carry_the_level_and_values_with_units(session):
    _, got, _, _ = session
    status = got["diag"][-1]
    assert status.level == b"\x02"  # ERROR
    # the driver's naming scheme and hardware id (one motor, one namespace)
    assert status.name == "monitor_node: motor drift" and status.hardware_id == "pmdc_motor"
    values = {kv.key: kv.value for kv in status.values}
    assert re.fullmatch(r"\d{10}\.\d{3}", values["t_s"]), values["t_s"]  # not 1.79577e+09
    assert float(values["resistance_ohm"]) > 1.375 * 1.2
    assert values["resistance_level"] == "ERROR"
    assert values["suggest_reidentify"] == "true"
    assert "back_emf_V_s_per_rad" in values and "delay_ci95_s" in values


def test_resistance_is_plottable_on_its_own_topic(session):
    _, got, _, _ = session
    assert got["typed"], "nothing on model_drift/resistance"
    last = got["drift"][-1]["quantities"]["resistance"]
    arrays = [list(m.data) for m in got["typed"]]
    est, lo, hi, ref, level = arrays[-1]
    assert ref == pytest.approx(1.375) and level == 2.0  # identified R, ERROR
    assert lo < est < hi and est > 1.2 * 1.375
    assert any(a[0] == pytest.approx(last["value"]) for a in arrays[-5:])
    (dim,) = got["typed"][-1].layout.dim
    assert dim.label == "resistance [ohm]: estimate,ci95_low,ci95_high,identified,level"


def test_the_suggestion_is_latched_and_reset_by_service(session):  # noqa: D103
    client, got, _, _ = session
    assert got["suggest"][-1]["suggest_reidentify"] is True
    assert "resistance" in got["suggest"][-1]["reason"]
    before = got["suggest"][-1]
    # The motor stops being driven: its armature open, the data say nothing about R.
    # The watchdog would open it 0.5 s after the last command, but the reset below can
    # come sooner than that (the tests before it take milliseconds): then the still-hot
    # motor, driven, would rightly prove its R drift again. So open it, and wait for
    # the monitor to report on samples of the open armature.
    client.open_armature()
    opened_s = client.get_clock().now().nanoseconds * 1e-9
    end = time.monotonic() + 10.0
    while time.monotonic() < end and got["drift"][-1]["t_s"] < opened_s + 0.2:
        client.spin_once(0.05)
    assert got["drift"][-1]["t_s"] >= opened_s + 0.2, "the monitor reported nothing after"
    n = len(got["suggest"])
    assert client.trigger("reset_suggestion") == "re-identify suggestion cleared"
    # The reset publishes False and starts the estimates over: no new evidence comes, so
    # the suggestion stays cleared. It used to re-latch at the next report, 20 ms later,
    # from the old estimate (issue 24); an old estimate kept with the levels reset would
    # prove ERROR again hold_s (1 s) later. So watch the reports on 1.5 s of samples
    # after the reset (about 1.5 s of wall time; it was a fixed 3 s).
    reset_s = client.get_clock().now().nanoseconds * 1e-9
    end = time.monotonic() + 15.0
    while time.monotonic() < end and got["drift"][-1]["t_s"] < reset_s + 1.5:
        client.spin_once(0.05)
    assert got["drift"][-1]["t_s"] >= reset_s + 1.5, "the monitor reported nothing after"
    after = got["suggest"][n:]
    assert after, "nothing published after the reset"
    assert all(a["suggest_reidentify"] is False for a in after), (before, after)
    assert after[-1]["schema_version"] == 1


def test_a_missing_motor_file_is_one_line_and_exit_2(tmp_path, ros_domain):
    with MonitorProcess({"params": str(tmp_path / "none.yaml")}, domain_id=ros_domain) as proc:
        proc.proc.wait(timeout=60)
    rc = proc.stop()
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert rc == 2
    assert len(lines) == 1 and "parameter params" in lines[0]


def _dds_up(pid: int) -> bool:
    """The process holds a socket: its DDS participant exists, imports are done."""
    fd_dir = Path(f"/proc/{pid}/fd")
    try:
        links = [os.readlink(fd) for fd in fd_dir.iterdir()]
    except OSError:
        return False
    return any(link.startswith("socket:") for link in links)


def test_sigint_stops_the_node_with_exit_0(ros_domain):
    with MonitorProcess({"params": "seed000_ebike"}, domain_id=ros_domain) as proc:
        end = time.monotonic() + 60.0
        while time.monotonic() < end and proc.alive() and not _dds_up(proc.pid):
            time.sleep(0.02)
        assert proc.alive(), proc.stderr
        assert proc.stop(signal.SIGINT, timeout_s=20.0) == 0, proc.stderr
        assert "Traceback" not in proc.stderr


def test_diagnostics_go_stale_when_the_driver_stops(session):
    """The last test of the shared session: it stops the driver. The monitor then says
    STALE (it republished its last ERROR forever) and logs the change (issue 24)."""
    client, got, monitor, driver = session
    assert driver.stop() == 0, driver.stderr
    n = len(got["diag"])
    end = time.monotonic() + 15.0  # stale_s 1 s, then the next 0.5 s report
    while time.monotonic() < end and not any(st.level == b"\x03" for st in got["diag"][n:]):
        client.spin_once(0.05)
    stale = [st for st in got["diag"][n:] if st.level == b"\x03"]
    assert stale, [st.message for st in got["diag"][n:]]
    # the last report is named: OK where the suggestion's reset ran before in this
    # process and started the estimates over, ERROR where the test ran first or alone
    # (pytest-xdist's worksteal may give a module's tests to two processes)
    last = re.match(r"no driver samples for \d+\.\d s; last report (OK|ERROR)", stale[-1].message)
    assert last, stale[-1].message
    assert monitor.stop() == 0
    assert f"motor drift: {last[1]} -> STALE: no driver samples for" in monitor.stderr
