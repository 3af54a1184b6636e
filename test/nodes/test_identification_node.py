"""End to end over DDS: driver, recorder and identification nodes in separate processes.

Each test runs one session through :func:`pmdc_ident.process.bringup.run_session`
on the simulated motor, with a probe process that records what the driver
really applied (``voltage_applied``) and the session's markers and status. The
probe is independent of the nodes under test, so "the motor is safe after an
abort" is checked on the driver's own telemetry.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import psutil
import pytest
import yaml
from helpers.paths import REPO
from helpers.plans import SHORT_SEQUENCE  # noqa: E402

from pmdc_ident.core.errors import DataError
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio.bagio import read_bag, read_driver_arrays
from pmdc_ident.dataio.mcap_recover import scan_mcap
from pmdc_ident.exports import EXPORT_FILES
from pmdc_ident.process.bringup import (
    BringupResult,
    node_env,
    priority_setter,
    realtime_thread,
    run_session,
)
from pmdc_ident.process.dds_domain import HELD_ENV

pytestmark = [pytest.mark.ros, pytest.mark.slow]

DT = 1e-3
# A short sequence on the seed-001 motor (tau_m = 50 ms): about 5 s of driver time.
# This machine is shared (2 cores, other test suites running): the node's default
# data timeout (3 s, issue 24) tolerates its scheduling stalls.
SHORT = dict(SHORT_SEQUENCE)

_PROBE = r"""
import json, signal, sys, time
import rclpy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from pmdc_ident.dataio.bagio import parse_joint_state
from pmdc_ident.nodes.qos import LATCHED_QOS, SEGMENT_QOS, sample_qos

rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
stop = []
signal.signal(signal.SIGINT, lambda *a: stop.append(1))
signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
node = rclpy.create_node("probe")
out = {"v": [], "markers": [], "status": [], "result": None}
def on_v(raw):
    ns, _, _, v, _ = parse_joint_state(raw)
    if not out["v"]:
        print("probe receiving", file=sys.stderr, flush=True)
    out["v"].append([ns, v])
node.create_subscription(JointState, "voltage_applied", on_v, sample_qos(1000), raw=True)
node.create_subscription(String, "segment", lambda m: out["markers"].append(m.data), SEGMENT_QOS)
node.create_subscription(String, "status", lambda m: out["status"].append(m.data), LATCHED_QOS)
from diagnostic_msgs.msg import DiagnosticArray
out["skipped"] = 0
def on_diag(msg):
    for st in msg.status:
        for kv in st.values:
            if kv.key.startswith("skipped samples"):
                out["skipped"] = max(out["skipped"], int(kv.value))
node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 10)
def on_result(m):
    out["result"] = m.data
node.create_subscription(String, "identified_parameters", on_result, LATCHED_QOS)
from std_msgs.msg import Float64MultiArray
out["typed"] = {}
def on_typed(name):
    def cb(m):
        data = [None if x != x else x for x in m.data]
        out["typed"][name] = {"data": data, "label": [d.label for d in m.layout.dim]}
    return cb
for name in ("R", "Kt"):
    node.create_subscription(
        Float64MultiArray, "identified_parameters/" + name, on_typed(name), LATCHED_QOS
    )
from rclpy.experimental import EventsExecutor
ex = EventsExecutor()
ex.add_node(node)
print("probe ready", file=sys.stderr, flush=True)
deadline = time.monotonic() + float(sys.argv[1])
while not stop and time.monotonic() < deadline:
    ex.spin_once(timeout_sec=0.05)
# stopped: take what is still queued for us (nothing new for 0.3 s), then report
seen, quiet_since, end = -1, time.monotonic(), time.monotonic() + 10.0
while time.monotonic() < end and time.monotonic() - quiet_since < 0.3:
    n = len(out["v"]) + len(out["status"]) + len(out["markers"])
    if n != seen:
        seen, quiet_since = n, time.monotonic()
    ex.spin_once(timeout_sec=0.05)
out["v"] = [[a, None if v != v else v] for a, v in out["v"]]
print(json.dumps(out), flush=True)
node.destroy_node()
rclpy.try_shutdown()
"""


def _start_probe(domain: int, timeout_s: float, stderr: Any) -> subprocess.Popen[str]:
    """The probe (``_PROBE``) on ``domain``, at the nodes' priority: it observes as they run."""
    return subprocess.Popen(
        [sys.executable, "-c", _PROBE, str(timeout_s + 30)],
        env=node_env(domain),
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=stderr,
        text=True,
        preexec_fn=priority_setter(-5, realtime=True),
    )


def _probe_report(out: str) -> dict[str, Any]:
    """What the probe saw, from its last line of output."""
    data = json.loads(out.strip().splitlines()[-1])
    data["markers"] = [json.loads(m) for m in data["markers"]]
    data["status"] = [json.loads(s) for s in data["status"]]
    return data


def _session(
    tmp_path: Path,
    domain: int,
    *,
    motor: str = "seed001_110v",
    ident: dict[str, Any] | None = None,
    driver: dict[str, Any] | None = None,
    recorder: dict[str, Any] | None = None,
    during: Any = None,
    timeout_s: float = 120.0,
    short: bool = True,
    hold_probe_until: str | None = None,
) -> tuple[BringupResult, dict[str, Any]]:
    """One session, seen whole by the probe: the identification node starts once the
    probe receives the driver's samples (``autostart``; started with the driver and the
    recorder instead, the three nodes' start-up made a session on the other core miss its
    timing checks: 2929e25).
    ``hold_probe_until``: the probe, receiving, is stopped (SIGSTOP: a reader held up on
    a busy machine) while the node starts, until the node's log says this."""
    probe = _start_probe(domain, timeout_s, subprocess.PIPE)

    def probe_receiving() -> None:  # the whole session is seen by the probe
        assert probe.stderr is not None
        deadline = time.monotonic() + 120.0
        for line in probe.stderr:
            if "probe receiving" in line or time.monotonic() > deadline:
                if hold_probe_until is not None:
                    probe.send_signal(signal.SIGSTOP)
                return
        raise AssertionError("the probe exited before receiving a driver sample")

    def watch(procs: dict[str, subprocess.Popen[bytes]], elapsed: float) -> None:
        if hold_probe_until is not None:
            log = (tmp_path / "logs" / "identification.log").read_text()
            if hold_probe_until in log:
                probe.send_signal(signal.SIGCONT)
        if during is not None:
            during(procs, elapsed)

    try:
        # the test's watch (``during``) reacts at the nodes' priority, as they run
        with realtime_thread():
            res = run_session(
                output_dir=tmp_path / "out",
                motor=motor,
                domain_id=domain,
                before_identification=probe_receiving,
                identification_params={**(SHORT if short else {}), **(ident or {})},
                driver_params={"watchdog_s": 1.5, **(driver or {})},
                recorder_params={"margin_s": 0.0, **(recorder or {})},
                log_dir=tmp_path / "logs",
                timeout_s=timeout_s,
                during=watch,
            )
    finally:
        probe.send_signal(signal.SIGCONT)
        probe.send_signal(signal.SIGINT)  # it takes what is still queued, then reports
        out, err = probe.communicate(timeout=60)
    assert probe.returncode == 0, err
    return res, _probe_report(out)


def _ident_log(res: BringupResult) -> str:
    return res.logs["identification"].read_text()


def _logs(res: BringupResult) -> str:
    return "\n".join(f"== {k}\n{p.read_text()[-3000:]}" for k, p in res.logs.items())


def _assert_every_published_sample(arrays: Any, expected: int, probe: dict[str, Any]) -> None:
    """The bag holds every driver sample of the session on all three topics.

    A driver held up past its catch-up limit skips samples itself (it reports the
    count on /diagnostics); those are missing on all three topics alike and are
    the only ones allowed to be missing.
    """
    np.testing.assert_array_equal(arrays.encoder_ns, arrays.current_ns)
    np.testing.assert_array_equal(arrays.encoder_ns, arrays.voltage_ns)
    n = arrays.encoder_ns.size
    assert expected - probe["skipped"] <= n <= expected, (n, expected, probe["skipped"])
    if probe["skipped"] == 0:
        assert np.all(np.abs(np.diff(arrays.encoder_ns) - 1_000_000) < 1_000)


def _applied(probe: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    v = np.array([[a, np.nan if b is None else b] for a, b in probe["v"]], dtype=float)
    return v[:, 0] * 1e-9, v[:, 1]


# ---------------------------------------------------------------------------
# The short sequence: every sample recorded, the bag reads back, offline = online
# ---------------------------------------------------------------------------
@pytest.fixture(scope="module")
def short_run(tmp_path_factory, module_ros_domain) -> SimpleNamespace:
    """The short session, shared by the tests below that only read its outcome.

    As a larger stack would run it: the node waits (``autostart`` off, and it stays up
    after the session, ``exit_when_done`` off) until a caller asks by service; once it
    has identified, a late joiner subscribes to the latched result, and so does the
    integration guide's consumer (``examples/result_listener.py``); then the node gets
    Ctrl-C. With the exports on: the identified motor is also written for MuJoCo, URDF, ...
    """
    tmp_path = tmp_path_factory.mktemp("short")
    env = node_env(module_ros_domain)
    state: dict[str, Any] = {}

    def helper(*argv: str) -> subprocess.Popen[str]:
        return subprocess.Popen(
            [sys.executable, *argv],
            env=env,
            cwd=REPO,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )

    def drive(procs: dict[str, subprocess.Popen[bytes]], elapsed: float) -> None:
        log = (tmp_path / "logs" / "identification.log").read_text()
        if "call" not in state:  # started with the node: it waits for the service to appear
            state["call"] = helper("-c", _CALL, "call")
        if "identified from" in log and "late" not in state:
            state["late"] = helper("-c", _CALL, "late")  # starts after the result was published
            # and the integration guide's consumer, a node of another package
            state["example"] = helper(
                str(REPO / "examples" / "result_listener.py"), "--timeout", "60"
            )
        waiting = [state[k] for k in ("late", "example") if k in state]
        done = len(waiting) == 2 and all(w.poll() is not None for w in waiting)
        # a session that ended without a result (aborted, failed) has no late joiner to
        # wait for: the node is stopped as well, and the tests below say what went wrong
        ended = "identified from" not in log and re.search(r"ABORTED|identification failed", log)
        if (done or ended) and "stopped" not in state:
            procs["identification"].send_signal(signal.SIGINT)
            state["stopped"] = True

    try:
        res, probe = _session(
            tmp_path,
            module_ros_domain,
            ident={"export_models": True, "autostart": False, "exit_when_done": False},
            during=drive,
        )
        outputs = {k: p.communicate(timeout=30) + (p.returncode,) for k, p in state.items()
                   if isinstance(p, subprocess.Popen)}  # fmt: skip
    finally:
        for p in state.values():
            if isinstance(p, subprocess.Popen) and p.poll() is None:
                p.kill()
                p.communicate()
    return SimpleNamespace(res=res, probe=probe, outputs=outputs)


@pytest.fixture(scope="module")
def short_session(short_run) -> tuple[BringupResult, dict[str, Any]]:
    return short_run.res, short_run.probe


def test_short_session_completes_and_the_bag_holds_every_driver_sample(short_session):
    res, probe = short_session
    assert res.identification_rc in (0, 1, 2), _logs(res)
    assert res.bag is not None, _logs(res)
    arrays = read_driver_arrays(res.bag)
    ms = arrays.markers
    events = [m.event.value for m in ms]
    assert events[0] == "session_start" and events[-1] == "session_end", events
    assert "abort" not in events
    expected = round((ms[-1].t_s - ms[0].t_s) / DT)
    _assert_every_published_sample(arrays, expected, probe)
    # what is missing (only samples the driver skipped may be) is said in the bag's
    # metadata and in parameters.json, in the same words
    meta = yaml.safe_load((res.bag / "metadata.yaml").read_text())
    said = json.loads(
        meta["rosbag2_bagfile_information"]["custom_data"]["pmdc_ident.driver_samples"]
    )
    assert said["missing_max"] == expected - arrays.encoder_ns.size, said
    assert said["topics"]["encoder"]["expected"] == expected
    assert res.result is not None and res.result["driver_samples"] == said
    run = read_bag(res.bag)
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(
        spec,
        DT,
        SequenceConfig(**{k[9:]: v for k, v in SHORT.items() if k.startswith("sequence.")}),
    )
    assert run.labels == tuple(p.label for p in plan.segments)
    assert sum(s.n for s in run.segments) == arrays.encoder_ns.size
    # non-staircase segments hold exactly their planned number of driver samples
    for seg, p in zip(run.segments, plan.segments, strict=True):
        if not seg.label.startswith("staircase"):
            assert seg.n + probe["skipped"] >= p.voltage.size >= seg.n, seg.label
        else:  # staircase levels wait for steady state: at least half the nominal hold
            assert seg.n >= p.voltage.size // 2
    # the applied voltage follows the plan: commands reach the driver within 100 ms (a few ms
    # on an idle machine; more than 50 ms was seen with a load average of 9 on 2 cores)
    step = run.segments[[s.label for s in run.segments].index("step_up")]
    v = step.voltage
    n_rest = plan.segments[3].voltage.size // 6
    assert np.median(v[-50:]) == pytest.approx(0.5 * 110.0, rel=1e-9)
    assert np.all(v[50:n_rest] == 0.0)  # the rest before the step (after the latency)
    k_rise = 50 + int(np.argmax(v[50:] > 27.5))
    assert 0 <= k_rise - n_rest < 100, k_rise - n_rest
    # the coast: the armature opens once the command arrives and stays open to the end.
    # Its ~1 s opens within 0.6 s of the segment's start: 0.39 s late was seen with three
    # benchmarks beside the suite (load 12 on 2 cores); the step above bounds the usual
    coast = run.segments[-1].open_mask
    assert coast[-1] and np.all(np.diff(coast.astype(int)) >= 0), coast
    assert coast.size - coast.sum() < 600, coast.size - coast.sum()


def test_the_result_is_versioned_typed_and_names_its_bag_by_absolute_path(short_session):
    """Issue 24: schema_version, sources as an absolute path, Kt under the Kt = Ke
    closure not identifiable, one plottable array per parameter, a unique session id."""
    res, probe = short_session
    result = res.result
    assert result is not None, _logs(res)
    assert result["schema_version"] == 1
    assert [Path(x) for x in result["sources"]] == [res.bag.absolute()]
    kt = result["parameters"]["Kt"]
    assert kt["identifiable"] is False and kt["reason"].startswith("assumed equal to Ke")
    r = result["parameters"]["R"]
    typed = probe["typed"]
    assert typed["R"]["data"] == [r["value"], *r["ci95"], r["stderr"], 1.0], typed
    assert typed["R"]["label"] == ["R [ohm]: value,ci95_low,ci95_high,stderr,identifiable"]
    assert typed["Kt"]["data"][4] == 0.0
    assert re.fullmatch(r"session_\d{8}_\d{6}_[0-9a-f]{6}", res.bag.name), res.bag.name
    assert all(st["schema_version"] == 1 for st in probe["status"])


def test_independent_mcap_ros2_decoder_reads_the_session_bag(short_session):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    res, _ = short_session
    counts: dict[str, int] = {}
    with next(res.bag.glob("*.mcap")).open("rb") as f:
        for _, ch, _, _ in make_reader(
            f, decoder_factories=[DecoderFactory()]
        ).iter_decoded_messages():
            counts[ch.topic] = counts.get(ch.topic, 0) + 1
    n = read_driver_arrays(res.bag).encoder_ns.size
    assert counts["/current"] == counts["/encoder"] == counts["/voltage_applied"] == n
    assert counts["/segment"] == 2 * 7 + 2
    assert counts["/voltage_cmd"] > 100


def test_offline_reidentification_of_the_bag_matches_the_online_result(short_session):
    pytest.importorskip("pmdc_ident.commands.identify")
    from pmdc_ident.process.identify_call import identify_session_run

    res, probe = short_session
    assert res.result is not None, _logs(res)
    online = json.loads(probe["result"])
    assert online == res.result  # the latched topic and the file beside the bag agree
    offline = json.loads(identify_session_run(read_bag(res.bag)).json_text)
    for name, p in online["parameters"].items():
        assert f"{p['value']:.6g}" == f"{offline['parameters'][name]['value']:.6g}", name
    # and through the command line, exactly as a user on a laptop would
    out = res.bag.parent / "offline.json"
    cli = subprocess.run(
        [sys.executable, "-m", "pmdc_ident.cli", "identify", str(res.bag), "--json", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert cli.returncode == 0, cli.stderr
    by_cli = json.loads(out.read_text())
    for name, p in online["parameters"].items():
        assert f"{p['value']:.6g}" == f"{by_cli['parameters'][name]['value']:.6g}", name
    # the whole document: the node runs the command's service (gate, segments, fit, bias
    # flag, JSON), so only the session's own entries and what the bag file adds differ
    # (docs/reference.md, "The result document")
    assert set(by_cli) <= set(online), set(by_cli) - set(online)  # inputs, recording, ...
    assert set(online) - set(by_cli) <= {"driver_samples", "exports", "experiment_design"}
    node_doc, cli_doc = _without_session_fields(online), _without_session_fields(by_cli)
    node_doc = _in_cli_words(node_doc)  # the node names its parameter where the CLI a flag
    assert node_doc.keys() == cli_doc.keys()
    differ = [k for k in node_doc if node_doc[k] != cli_doc[k]]
    assert differ == [], {k: (node_doc[k], cli_doc[k]) for k in differ}


# entries of the node's result that `pmdc-ident identify --json` on its bag does not have
# or words otherwise (docs/reference.md): the session's own, and the input as read
SESSION_FIELDS = ("driver_samples", "exports", "experiment_design", "inputs", "recording")
TIMINGS = ("elapsed_s",)


def _in_cli_words(doc: Any) -> Any:
    """``doc`` with the node's words for an option (``parameter fix``) as the command's."""
    from pmdc_ident.app.options import CLI_NAMES
    from pmdc_ident.process.identify_call import NODE_NAMES

    text = json.dumps(doc)
    for key, flag in CLI_NAMES.items():
        text = text.replace(json.dumps(NODE_NAMES[key])[1:-1], flag)
    return json.loads(text)


def _without_session_fields(doc: Any) -> Any:
    if isinstance(doc, dict):
        return {
            k: _without_session_fields(v)
            for k, v in doc.items()
            if k not in SESSION_FIELDS and k not in TIMINGS and k != "recording_complete"
        }
    if isinstance(doc, list):
        return [_without_session_fields(v) for v in doc]
    return doc


def test_session_recovers_the_simulated_motor(short_session):
    pytest.importorskip("pmdc_ident.commands.identify")
    res, _ = short_session
    assert res.result is not None, _logs(res)
    truth = load_motor("seed001_110v").model.params
    got = {k: v["value"] for k, v in res.result["parameters"].items()}
    # light noise, 5 s of rich data: R, Ke within 2 %, J and B within 5 %
    assert got["R"] == pytest.approx(truth.R, rel=0.02)
    assert got["Ke"] == pytest.approx(truth.Ke, rel=0.02)
    assert got["J"] == pytest.approx(truth.J, rel=0.05)
    assert got["B"] == pytest.approx(truth.B, rel=0.05)
    assert (res.bag / "parameters.yaml").is_file()


def test_the_node_writes_the_exports_beside_the_bag(short_session):
    """export_models:=true: MJCF, URDF, ros2_control and gains beside the bag, said in
    the published result; the MJCF loads in MuJoCo and the URDF parses."""
    res, _ = short_session
    assert res.result is not None, _logs(res)
    names = ["identified" + suffix for suffix in EXPORT_FILES]
    assert res.result["exports"] == {"files": names, "error": None}, _logs(res)
    mjcf, urdf_path, control, gains = (res.bag / n for n in names)
    assert "exports written to" in res.logs["identification"].read_text()
    assert yaml.safe_load(control.read_text())
    assert yaml.safe_load(gains.read_text())["sample_rate_hz"] == pytest.approx(1000.0)
    try:
        import mujoco
    except ImportError:
        assert ET.parse(mjcf).getroot().tag == "mujoco"
    else:
        model = mujoco.MjModel.from_xml_path(str(mjcf))
        assert model.nu == 1 and model.njnt == 1
    try:
        from urdf_parser_py.urdf import URDF
    except ImportError:
        assert ET.parse(urdf_path).getroot().tag == "robot"
    else:
        robot = URDF.from_xml_string(urdf_path.read_text())
        assert robot.joints[0].dynamics is not None
        assert robot.joints[0].name == "motor_joint"  # the driver's joint_name
    # the file beside the bag loads in a node with --params-file (issue 24)
    import rclpy
    from rclpy.context import Context

    ctx = Context()
    rclpy.init(args=["--ros-args", "--params-file", str(control)], context=ctx)
    rclpy.shutdown(context=ctx)


# ---------------------------------------------------------------------------
# Aborts: every path leaves zero volts on the motor
# ---------------------------------------------------------------------------
def _abort_marker(probe: dict[str, Any]) -> dict[str, Any]:
    aborts = [m for m in probe["markers"] if m["event"] == "abort"]
    assert len(aborts) == 1, probe["markers"]
    return aborts[0]


def _assert_safe_after(
    probe: dict[str, Any], t_abort: float, *, strict_zero: bool, log: str | None = None
) -> None:
    if log is not None:  # the node itself saw the driver report the safe state (its log)
        assert "motor confirmed safe by the driver" in log
    t, v = _applied(probe)
    after = t >= t_abort
    assert after.sum() >= 100, "the probe saw too little of the driver after the abort"
    tail = v[-50:]
    assert np.all((tail == 0.0) | np.isnan(tail)), tail  # never a voltage left applied
    if strict_zero:
        # safe_mode zero: exactly 0 V comes from the identification node (the driver's
        # watchdog would open the armature, NaN, and only after 0.5 s without commands)
        zero = np.flatnonzero(after & (v == 0.0))
        assert zero.size, "0 V never applied after the abort"
        # well before the driver's 1.5 s watchdog (host latency on a loaded machine)
        assert t[zero[0]] - t_abort < 1.0, t[zero[0]] - t_abort
        later = v[zero[0] :]
        assert np.all((later == 0.0) | np.isnan(later)), later[(later != 0.0)][:5]


def test_a_session_over_without_a_job_stops_its_worker_when_the_node_winds_down():
    """An aborted or refused session leaves its identification worker warming up (~2 s of
    CPU for nothing): wind-down stops it first, before the node confirms the safe state
    and lingers for late readers. A worker with a job (a stop while identifying) is left
    to finish it, and a session still running keeps its worker."""
    from pmdc_ident.node_logic.session.controller import Phase
    from pmdc_ident.nodes.identification_node import MIN_LIFE_S, IdentificationNode
    from pmdc_ident.process.identify_call import IdentificationWorker

    class Controller:  # finished, confirming the safe state for one spin
        def __init__(self, phase: Phase) -> None:
            self.phase, self.exit_code, self._confirming = phase, 3, iter([True, False])

        @property
        def confirming(self) -> bool:
            return next(self._confirming)

        def confirm_tick(self, now_s: float) -> None:
            pass

    def node(phase: Phase, worker: IdentificationWorker) -> SimpleNamespace:
        """What wind-down reads of the node (no DDS), its minimum life over."""
        n = SimpleNamespace(_worker=worker, _built_s=time.monotonic() - MIN_LIFE_S)
        n.controller = Controller(phase)
        n.wait_delivered = lambda timeout_s: True
        n._stop_idle_worker = lambda: IdentificationNode._stop_idle_worker(n)
        return n

    seen: list[bool] = []
    idle = IdentificationWorker()
    n = node(Phase.FINISHED, idle)
    IdentificationNode.wind_down(n, lambda timeout_s: seen.append(idle.alive))
    assert seen == [False] and n._worker is None  # gone before the first confirming spin
    busy, running = IdentificationWorker(), IdentificationWorker()
    try:
        busy._busy = True  # a job submitted, its outcome not yet in
        for phase, worker in ((Phase.FINISHED, busy), (Phase.RUNNING, running)):
            n = node(phase, worker)
            IdentificationNode.wind_down(n, lambda timeout_s: None)
            assert n._worker is worker and worker.alive, phase
    finally:
        busy.terminate()
        running.terminate()


def _variant(tmp_path: Path, name: str, **changes: Any) -> str:
    """A seed-001 motor file with changed parameters or effects (the 'real' motor)."""
    data = yaml.safe_load((REPO / "config" / "motors" / "seed001_110v.yaml").read_text())
    data["name"] = name
    data["parameters"].update(changes.pop("parameters", {}))
    data["effects"] = changes.pop("effects", data["effects"])
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def _stall_motor(tmp_path: Path) -> str:
    # 80 N*m of Coulomb friction > Kt * 40 A: the rotor never turns
    return _variant(tmp_path, "locked", effects={"coulomb_friction": {"torque_nm": 80.0}})


@pytest.mark.parametrize(
    ("reason", "ident", "real"),
    [
        # 36.7 V into 3 ohm draws 12 A at the first staircase level
        ("over_current", {"safety.current_max_a": 8.0}, None),
        # plan checked against the nominal motor (47 rad/s at 90 V < 55), but the
        # motor on the bench has a weaker magnet and runs to ~69 rad/s
        (
            "over_speed",
            {"safety.speed_max_rad_s": 55.0, "voltage_max_v": 90.0},
            {"Ke": 1.2, "Kt": 1.2},
        ),
    ],
)
def test_safety_abort_leaves_zero_volts(tmp_path, reason, ident, real, ros_domain):
    driver = None
    if real is not None:
        driver = {"motor": _variant(tmp_path, "weak_magnet", parameters=real)}
    res, probe = _session(tmp_path, ros_domain, ident=ident, driver=driver)
    assert res.identification_rc == 3, _logs(res)
    marker = _abort_marker(probe)
    final = probe["status"][-1]
    assert final["state"] == "aborted" and final["reason"] == reason, probe["status"]
    _assert_safe_after(probe, marker["t_s"], strict_zero=True, log=_ident_log(res))
    assert res.result is None  # nothing identified from an aborted session


def test_stall_aborts_when_current_flows_and_the_shaft_does_not_turn(tmp_path, ros_domain):
    motor = _stall_motor(tmp_path)
    ident = {
        "motor": "seed001_110v",  # the nominal motor sizes the plan; the real one is locked
        "safety.stall_current_a": 5.0,
        "safety.stall_time_s": 0.2,
    }
    res, probe = _session(tmp_path, ros_domain, ident=ident, driver={"motor": motor})
    assert res.identification_rc == 3, _logs(res)
    final = probe["status"][-1]
    assert final["reason"] == "stall", probe["status"]
    marker = _abort_marker(probe)
    # 36.7 V into 3 ohm: 12 A within ~20 ms (L/R = 34 ms) of the voltage reaching the
    # motor, so the stall is called stall_time_s = 0.2 s later (plus host latency)
    t, v = _applied(probe)
    t_on = t[np.flatnonzero(v > 1.0)[0]]
    assert 0.2 <= marker["t_s"] - t_on < 0.2 + 0.15, marker["t_s"] - t_on
    _assert_safe_after(probe, marker["t_s"], strict_zero=True, log=_ident_log(res))


def _act_mid_session(
    tmp_path: Path,
    domain: int,
    act: Callable[[dict[str, subprocess.Popen[bytes]]], object],
    after_s: float = 1.0,
    **session: Any,
) -> tuple[BringupResult, dict[str, Any]]:
    """A short session in which ``act(procs)`` runs once, ``after_s`` after the session
    started (asserted to have happened)."""
    state: dict[str, float] = {}

    def during(procs: dict[str, subprocess.Popen[bytes]], elapsed: float) -> None:
        log = (tmp_path / "logs" / "identification.log").read_text()
        if "segments, nominal" in log and "acted" not in state:
            state.setdefault("seen", elapsed)
            if elapsed - state["seen"] > after_s:
                act(procs)
                state["acted"] = elapsed

    res, probe = _session(tmp_path, domain, during=during, **session)
    assert "acted" in state, _logs(res)
    return res, probe


def _bringup_with_probe(
    tmp_path: Path,
    domain: int,
    env: dict[str, str],
    during: Callable[[subprocess.Popen[str], list[str]], None],
    params: dict[str, Any] | None = None,
    timeout_s: float = 120.0,
) -> SimpleNamespace:
    """``bringup``, the command a user runs, on the short sequence in ``env``, with the
    probe watching: ``during(bringup, lines so far)`` is called about every 50 ms once
    the probe receives the driver's samples, until bringup exits. Its exit status, its
    output (the nodes' log lines are in it), what the probe saw and the output folder."""
    out_dir = tmp_path / "out"
    probe_err = tmp_path / "probe.err"
    with probe_err.open("w") as err_file:
        probe = _start_probe(domain, timeout_s, err_file)
    settings = {f"identification:{k}": v for k, v in SHORT.items()}
    settings.update({"driver:watchdog_s": 1.5, "recorder:margin_s": 0.0, **(params or {})})
    cmd = [sys.executable, "-m", "pmdc_ident.process.bringup", "--motor", "seed001_110v"]
    cmd += ["--output-dir", str(out_dir), "--domain-id", str(domain)]
    for name, value in settings.items():
        cmd += ["-p", f"{name}={value}"]
    lines: list[str] = []
    proc = None
    try:
        proc = subprocess.Popen(
            cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
        )
        assert proc.stdout is not None
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout), daemon=True)
        reader.start()
        deadline = time.monotonic() + timeout_s
        with realtime_thread():  # the watch reacts at the nodes' priority, as they run
            while proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.05)
                if "probe receiving" in probe_err.read_text():
                    during(proc, lines)
        rc = proc.wait(timeout=30)
        reader.join(timeout=10)
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.communicate()
        probe.send_signal(signal.SIGINT)  # it takes what is still queued, then reports
        out, _ = probe.communicate(timeout=60)
    assert probe.returncode == 0, probe_err.read_text()
    return SimpleNamespace(rc=rc, text="".join(lines), probe=_probe_report(out), out=out_dir)


@pytest.fixture(scope="module")
def ctrl_c_run(tmp_path_factory, module_ros_domain) -> SimpleNamespace:
    """Ctrl-C in bringup's terminal (SIGINT to bringup, which forwards it to the
    identification node) 1 s into the short session, the probe watching: the session
    both tests below check."""
    tmp_path = tmp_path_factory.mktemp("ctrl_c")
    state: dict[str, float] = {}

    def interrupt(proc: subprocess.Popen[str], lines: list[str]) -> None:
        if "sent" in state or not any("segments, nominal" in ln for ln in lines):
            return
        state.setdefault("seen", time.monotonic())
        if time.monotonic() - state["seen"] > 1.0:
            proc.send_signal(signal.SIGINT)  # what Ctrl-C in the terminal does
            state["sent"] = time.monotonic()

    env = node_env(module_ros_domain)  # hands our domain lock to bringup
    run = _bringup_with_probe(tmp_path, module_ros_domain, env, interrupt)
    run.acted = "sent" in state
    return run


def test_ctrl_c_aborts_the_session_and_makes_the_motor_safe(ctrl_c_run):
    run, probe = ctrl_c_run, ctrl_c_run.probe
    assert run.acted, run.text
    assert run.rc == 130, run.text  # bringup exits with the node's status
    assert probe["status"][-1]["reason"] == "interrupted", probe["status"]
    _assert_safe_after(probe, _abort_marker(probe)["t_s"], strict_zero=True, log=run.text)
    # the bag was closed cleanly and holds the session up to the interruption
    (bag,) = run.out.iterdir()
    assert (bag / "metadata.yaml").is_file()
    assert read_bag(bag).labels[0] == "staircase_01"


def test_ctrl_c_on_bringup_is_forwarded_and_everything_stops_safe(ctrl_c_run):
    text = ctrl_c_run.text
    assert ctrl_c_run.acted, text
    assert ctrl_c_run.rc != 0, text
    assert "ABORTED (interrupted)" in text, text
    assert "motor confirmed safe by the driver" in text, text
    assert "driver stopped: motor safe" in text, text
    assert "Traceback" not in text, text


@pytest.fixture(scope="module")
def killed_recorder_run(tmp_path_factory, module_ros_domain) -> SimpleNamespace:
    """The recorder killed (SIGKILL) mid-session under ``bringup``, the probe watching,
    with an older session's bag and result in the output folder: the session both
    tests below check. bringup takes its own domain lock, as a user's would (in a
    private lock folder: the domain is held by this test)."""
    tmp_path = tmp_path_factory.mktemp("killed_recorder")
    old = tmp_path / "out" / "session_old"
    old.mkdir(parents=True)
    (old / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    (old / "parameters.json").write_text(json.dumps({"parameters": {"R": {"value": 99.0}}}))
    state: dict[str, Any] = {}

    # SIGKILL: no goodbye, as in a real crash, once the recorder has handed the first
    # segment and 0.7 s after it to the file (samples are held 0.5 s, chunks flushed
    # twice a second) on the topics a bag needs: under load one topic's samples can
    # reach the recorder later than another's, and a bag killed before any voltage is
    # written is refused (no 'voltage_applied' topic), rightly
    def kill(proc: subprocess.Popen[str], lines: list[str]) -> None:
        bags = list((tmp_path / "out").glob("*/*.mcap"))
        if "killed" in state or not bags or bags[0].stat().st_size == state.get("size"):
            return
        state["size"] = bags[0].stat().st_size
        try:
            messages = scan_mcap(bags[0]).messages
        except DataError:  # no complete chunk yet
            return
        # the first segment's end is in the file, and more than the recorder's hold of
        # samples after it: a segment a re-read can fit (killed on 500 samples alone,
        # they were once all before 'staircase_01' started: nothing to export, rightly)
        ends = [
            k
            for k, (t, _, data) in enumerate(messages)
            if t.endswith("/segment") and b'"event":"end"' in data
        ]
        after = [m[0] for m in messages[ends[0] :]] if ends else []
        if (
            min(sum(t.endswith(f"/{k}") for t in after) for k in ("encoder", "voltage_applied"))
            >= 700
        ):
            (recorder,) = [
                p
                for p in psutil.Process(proc.pid).children(recursive=True)
                if "recorder_node" in " ".join(p.cmdline())
            ]
            recorder.kill()
            state["killed"] = True

    env = node_env(module_ros_domain)
    env.pop(HELD_ENV, None)  # bringup takes the lock itself, as a user's would
    env["PMDC_DDS_LOCK_DIR"] = str(tmp_path / "locks")
    (tmp_path / "locks").mkdir()
    run = _bringup_with_probe(
        tmp_path, module_ros_domain, env, kill, params={"recorder:hold_s": 0.5}
    )
    run.acted = bool(state.get("killed"))
    return run


def test_crashed_recorder_aborts_the_session_and_its_bag_is_readable(killed_recorder_run, caplog):
    run, probe = killed_recorder_run, killed_recorder_run.probe
    assert run.acted, run.text
    assert run.rc == 3, run.text  # bringup exits with the node's status
    assert probe["status"][-1]["reason"] == "peer_crashed", probe["status"]
    _assert_safe_after(probe, _abort_marker(probe)["t_s"], strict_zero=True, log=run.text)
    # the bag its recorder never closed: no metadata.yaml, no footer, complete chunks read
    (bag,) = [p for p in run.out.iterdir() if p.name != "session_old"]
    assert not (bag / "metadata.yaml").exists()
    with caplog.at_level("WARNING", logger="pmdc_ident.bag"):
        arrays = read_driver_arrays(bag)
    (line,) = [r.getMessage() for r in caplog.records]
    assert "truncated bag (its recorder did not close it): read " in line, line
    assert arrays.markers[0].event.value == "session_start"
    start_ns = round(arrays.markers[0].t_s * 1e9)
    enc = arrays.encoder_ns[arrays.encoder_ns >= start_ns]
    assert enc.size >= 500, enc.size
    assert np.all(np.diff(enc) == 1_000_000) or probe["skipped"]  # nothing lost inside
    # the command line reads it too, says what was lost in one line, and exports it
    csv = run.out.parent / "k.csv"
    out = subprocess.run(
        [sys.executable, "-m", "pmdc_ident.cli", "export", str(bag), "--csv", str(csv)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert out.returncode == 0, out.stderr
    (note,) = out.stderr.strip().splitlines()
    assert "truncated bag" in note and "s into session" in note, note
    assert csv.stat().st_size > 0


def test_a_killed_recorder_aborts_and_bringup_reports_this_session_never_an_older_one(
    killed_recorder_run,
):
    """Issue 28 item 2: bringup says ABORTED, names this session's bag as incomplete and
    exits non-zero (it printed the previous session's bag, parameters and diagnosis,
    exit 0)."""
    text = killed_recorder_run.text
    assert killed_recorder_run.acted, text
    assert killed_recorder_run.rc not in (0, None), text
    assert "ABORTED" in text, text
    assert "session_old" not in text and "99" not in text.split("ABORTED")[-1], text
    assert "INCOMPLETE: its recorder did not close it" in text, text
    assert "Traceback" not in text, text


def test_lost_driver_data_aborts_and_the_driver_applies_the_safe_command(tmp_path, ros_domain):
    state: dict[str, Any] = {}

    def freeze(procs: dict[str, subprocess.Popen[bytes]], elapsed: float) -> None:
        log = (tmp_path / "logs" / "identification.log").read_text()
        if "segments, nominal" in log and "stopped" not in state:
            state.setdefault("seen", elapsed)
            if elapsed - state["seen"] > 1.0:
                os.kill(procs["driver"].pid, signal.SIGSTOP)  # the driver hangs
                state["stopped"] = elapsed
        elif "stopped" in state and "resumed" not in state and elapsed - state["stopped"] > 2.0:
            os.kill(procs["driver"].pid, signal.SIGCONT)
            state["resumed"] = elapsed

    res, probe = _session(
        tmp_path, ros_domain, during=freeze, ident={"safety.data_timeout_s": 1.0}
    )
    assert state.get("resumed"), _logs(res)
    assert res.identification_rc == 3, _logs(res)
    assert probe["status"][-1]["reason"] == "lost_driver_data", probe["status"]
    # the node kept sending 0 V until the driver, once resumed, reported a safe state
    # (0 V, or the armature its own watchdog opened after the freeze)
    assert "motor confirmed safe by the driver" in res.logs["identification"].read_text()
    t, v = _applied(probe)
    resumed = t > _abort_marker(probe)["t_s"] + 1.0
    assert resumed.sum() > 50  # the probe saw the driver run again
    tail = v[-50:]
    assert np.all((tail == 0.0) | np.isnan(tail)), tail


def test_full_default_sequence_recovers_the_seed000_motor(tmp_path, ros_domain):
    """The whole default session (staircase, steps both ways, chirp, coast-down) on the
    seed-000 e-bike motor, which carries Coulomb friction; about 40 s of driver time."""
    pytest.importorskip("pmdc_ident.commands.identify")
    res, probe = _session(
        tmp_path,
        ros_domain,
        motor="seed000_ebike",
        timeout_s=240,
        short=False,
    )
    assert res.identification_rc == 0, _logs(res)
    run = read_bag(res.bag)
    assert run.labels == (
        *(f"staircase_{k:02d}" for k in range(1, 7)),
        "step_up",
        "step_down",
        "sweep",
        "coast",
    )
    arrays = read_driver_arrays(res.bag)
    expected = round((arrays.markers[-1].t_s - arrays.markers[0].t_s) / DT)
    _assert_every_published_sample(arrays, expected, probe)
    truth = load_motor("seed000_ebike").model
    p = truth.params
    got = {k: v["value"] for k, v in res.result["parameters"].items()}
    # Kt = Ke closure: the mechanical side comes out scaled by Ke/Kt (0.982 here)
    scale = p.Ke / p.Kt
    assert got["R"] == pytest.approx(p.R, rel=0.01)
    assert got["Ke"] == pytest.approx(p.Ke, rel=0.01)
    assert got["J"] == pytest.approx(p.J * scale, rel=0.03)
    assert got["B"] == pytest.approx(p.B * scale, rel=0.10)
    tc = truth.effect("coulomb_friction").torque_nm
    assert got["coulomb_friction.torque_nm"] == pytest.approx(tc * scale, rel=0.03)
    # L/R = 0.22 ms below the 1 ms period: flagged from the fit's own bound (issue 9), and
    # the note says that L shows only in the first sample after a step and the current's lag;
    # the node reads its session through the same data-quality gate and assumption register
    # as `pmdc-ident identify <bag>` (issue 22), so where the gate measures the current
    # lagging the voltage column on this session, L carries that finding instead, as the
    # command's would
    reason = res.result["parameters"]["L"]["reason"]
    assert "below the sample period" in reason or "(gate: delay)" in reason, reason
    assert "assumptions_checked" in res.result and "quality" in res.result
    assert json.loads(probe["result"])["parameters"] == res.result["parameters"]


_CALL = r"""
import json, sys, time
import rclpy
from std_srvs.srv import Trigger
from std_msgs.msg import String
from pmdc_ident.nodes.qos import LATCHED_QOS

rclpy.init()
node = rclpy.create_node("caller")
what = sys.argv[1]
out = {}
if what == "call":
    cli = node.create_client(Trigger, "run_session")
    if cli.wait_for_service(timeout_sec=60.0):  # started with the node under test
        fut = cli.call_async(Trigger.Request())
        rclpy.spin_until_future_complete(node, fut, timeout_sec=20.0)
        r = fut.result()
        out = {"success": r.success, "message": r.message} if r else {}
else:  # a late joiner: the result must still arrive (transient local)
    got = []
    node.create_subscription(
        String, "identified_parameters", lambda m: got.append(m.data), LATCHED_QOS
    )
    t = time.monotonic()
    while not got and time.monotonic() - t < 20.0:
        rclpy.spin_once(node, timeout_sec=0.1)
    out = {"result": got[0] if got else None}
print(json.dumps(out), flush=True)
node.destroy_node()
rclpy.try_shutdown()
"""


def test_a_larger_stack_asks_for_a_run_by_service_and_a_late_joiner_gets_the_result(short_run):
    """The shared short session was started by a call of the ``run_session`` service; a
    late joiner and the integration guide's consumer, started after the result was
    published, both get it (see ``short_run``)."""
    pytest.importorskip("pmdc_ident.commands.identify")
    res, out = short_run.res, short_run.outputs
    assert {"call", "late", "example"} <= set(out), (sorted(out), _logs(res))
    call = json.loads(out["call"][0].strip().splitlines()[-1])
    assert call == {"success": True, "message": "session requested"}
    late = json.loads(out["late"][0].strip().splitlines()[-1])
    assert late["result"] is not None, _logs(res)
    assert json.loads(late["result"]) == res.result
    assert res.result["parameters"]["R"]["value"] == pytest.approx(3.0484, rel=0.02)
    text, err, rc = out["example"]
    assert rc == 0, err
    r = res.result["parameters"]["R"]
    (r_line,) = [ln.split() for ln in text.splitlines() if ln.split()[:1] == ["R"]]
    assert r_line[1:3] == [f"{r['value']:.6g}", "ohm"], text
    assert "NOT MEASURED: assumed equal to Ke" in text
    assert f"identified_parameters/R: [{r['value']!r}," in text, text


def test_a_plan_above_the_driver_limit_is_refused_before_anything_moves(tmp_path, ros_domain):
    """The driver is limited to 48 V; the session asks for 110 V. The probe, waiting
    for the session, is held up (stopped) from the node's start until the node has
    refused: the refusal still reaches it, as the node lives ``MIN_LIFE_S`` for readers
    still discovering it (a node that left once every reader it knew of had its status
    lost it: it cannot know of a reader it has not discovered)."""
    res, probe = _session(
        tmp_path,
        ros_domain,
        ident={"voltage_max_v": 110.0},
        driver={"voltage_limit_v": 48.0},
        hold_probe_until="plan refused before anything moved",
    )
    assert res.identification_rc == 2, _logs(res)
    final = probe["status"][-1]
    assert final["state"] == "refused", probe["status"]
    assert "110 V" in final["detail"] and "48 V" in final["detail"], final
    t, v = _applied(probe)
    assert t.size > 500 and np.all(np.isnan(v))  # the armature never closed
    assert res.bag is None and not probe["markers"]


def _node_alone(tmp_path, ros_domain, *params: str) -> subprocess.CompletedProcess[str]:
    """The identification node run on its own with ``-p`` for each of ``params``."""
    args = [a for p in params for a in ("-p", p)]
    return subprocess.run(
        [sys.executable, "-m", "pmdc_ident.nodes.identification_node", "--ros-args", *args],
        env=node_env(ros_domain),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )


def test_a_bad_parameter_is_one_line_and_exit_status_2(tmp_path, ros_domain):
    proc = _node_alone(tmp_path, ros_domain, "safe_mode:=banana")
    assert proc.returncode == 2
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "safe_mode" in lines[0] and "Traceback" not in proc.stderr, lines


def test_the_session_runs_against_the_virtual_serial_board_as_against_the_sim(
    tmp_path, ros_domain
):
    """Driver with backend serial on `pmdc-ident virtual-board` (a pty), same session."""
    pytest.importorskip("pmdc_ident.commands.identify")
    board = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "pmdc_ident.cli",
            "virtual-board",
            "--motor",
            "seed001_110v",
            "--baud",
            "1000000",
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=priority_setter(-5, realtime=True),  # hardware is never held up
    )
    try:
        first = board.stdout.readline().strip()
        assert first.startswith("virtual board on /dev/"), first
        port = first.split()[3]
        res, probe = _session(
            tmp_path,
            ros_domain,
            driver={"backend": "serial", "port": port, "baud": 1000000},
        )
    finally:
        board.send_signal(signal.SIGINT)
        board.communicate(timeout=20)
    assert res.identification_rc == 0, _logs(res)
    arrays = read_driver_arrays(res.bag)
    expected = round((arrays.markers[-1].t_s - arrays.markers[0].t_s) / DT)
    # Over a serial link on a loaded host the driver itself may skip a late backlog
    # (a gap on all three topics alike): the bag holds what the driver published.
    np.testing.assert_array_equal(arrays.encoder_ns, arrays.current_ns)
    np.testing.assert_array_equal(arrays.encoder_ns, arrays.voltage_ns)
    assert arrays.encoder_ns.size >= 0.97 * expected
    got = {k: v["value"] for k, v in res.result["parameters"].items()}
    truth = load_motor("seed001_110v").model.params
    assert got["R"] == pytest.approx(truth.R, rel=0.03)
    assert got["Ke"] == pytest.approx(truth.Ke, rel=0.03)


def test_sigterm_to_the_recorder_mid_session_closes_a_readable_bag(tmp_path, ros_domain):
    res, probe = _act_mid_session(
        tmp_path, ros_domain, lambda procs: procs["recorder"].send_signal(signal.SIGTERM)
    )
    assert res.recorder_rc == 0, _logs(res)
    # the session lost its recorder: aborted, motor safe
    assert probe["status"][-1]["reason"] == "peer_crashed", probe["status"]
    assert res.bag is not None and (res.bag / "metadata.yaml").is_file()
    arrays = read_driver_arrays(res.bag)  # rosbags reads it ...
    assert arrays.encoder_ns.size > 500
    assert np.all(np.diff(arrays.encoder_ns) < 1_500_000)
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    with next(res.bag.glob("*.mcap")).open("rb") as f:  # ... and so does mcap_ros2
        n = sum(
            1
            for _, ch, _, _ in make_reader(
                f, decoder_factories=[DecoderFactory()]
            ).iter_decoded_messages()
            if ch.topic == "/encoder"
        )
    assert n == arrays.encoder_ns.size


def test_without_a_driver_the_node_says_so_and_exits_2(tmp_path, ros_domain):
    proc = _node_alone(tmp_path, ros_domain, "driver_wait_s:=2.0", "exit_when_done:=true")
    assert proc.returncode == 2, proc.stderr
    assert "session not started, motor untouched: no driver node 'driver_node'" in proc.stderr
    assert "Traceback" not in proc.stderr
