"""The identification node's decisions without DDS: the SessionController driven by
hand (the node's callbacks) with a fake of the node's publications.

The closed-loop case runs the simulated plant sample by sample with the driver's
stamps, as the node sees them over DDS.
"""

from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET
from dataclasses import replace
from typing import Any

import numpy as np
import pytest
import yaml
from helpers.plans import SHORT_SEQUENCE

from pmdc_ident.core.enums import AbortReason, LogLevel, SafeMode
from pmdc_ident.core.excitation import SequenceConfig
from pmdc_ident.core.model import Plant
from pmdc_ident.core.motors import MotorSpec, load_motor
from pmdc_ident.core.safety import SafetyConfig
from pmdc_ident.exports import EXPORT_FILES
from pmdc_ident.node_logic.session.controller import ControllerConfig, Phase, SessionController
from pmdc_ident.node_logic.session.ports import (
    ExportRequest,
    IdentificationJob,
    IdentificationOutcome,
)
from pmdc_ident.node_logic.session.startup import (
    ABORT_FRACTION,
    DRIVER_PARAMETERS,
    SessionSettings,
    StartCheck,
    build_session,
)
from pmdc_ident.node_logic.session.steady_state import SteadyStateConfig
from pmdc_ident.process.parameter_tables import IDENTIFICATION
from pmdc_ident.process.settings import controller_config

DT = 1e-3
MOTOR = load_motor("seed001_110v")
DRIVER = {"voltage_limit_v": 110.0, "current_limit_a": 0.0, "speed_limit_rad_s": 0.0,
          "motor": "seed001_110v", "rate_hz": 1000.0}  # fmt: skip
SHORT = SHORT_SEQUENCE


class Ports:
    """Records what the controller publishes; the open_armature service is ready."""

    def __init__(self, service_ready: bool = True) -> None:
        self.service_ready = service_ready
        self.sent: list[float] = []
        self.opened = 0
        self.markers: list[dict] = []
        self.progress: list[dict] = []
        self.status: list[dict] = []
        self.results: list[str] = []
        self.logs: list[tuple[LogLevel, str]] = []
        self.asked: list[tuple[str, ...]] = []
        self.jobs: list[IdentificationJob] = []
        self.prepared: list[str] = []

    def send_voltage(self, voltage_v: float) -> None:
        self.sent.append(voltage_v)

    def open_armature(self) -> bool:
        self.opened += self.service_ready
        return self.service_ready

    def publish_marker(self, text: str) -> None:
        self.markers.append(json.loads(text))

    def publish_progress(self, text: str) -> None:
        self.progress.append(json.loads(text))

    def publish_status(self, text: str) -> None:
        self.status.append(json.loads(text))

    def publish_result(self, text: str) -> None:
        self.results.append(text)

    def request_driver_parameters(self, names: tuple[str, ...]) -> bool:
        self.asked.append(names)
        return True

    def prepare_identification(self, nominal: MotorSpec) -> None:
        self.prepared.append(nominal.name)

    def start_identification(self, job: IdentificationJob) -> None:
        self.jobs.append(job)

    def log(self, level: LogLevel, text: str) -> None:
        assert isinstance(level, LogLevel), (level, text)  # the ROS logger's severity, typed
        self.logs.append((level, text))


def _config(**overrides: Any) -> ControllerConfig:
    values = {**IDENTIFICATION.defaults(), "motor": "seed001_110v", **SHORT, **overrides}
    return controller_config(values)


def _ready(
    c: SessionController, now: float, clock_offset_ns: int = 0, driver: dict | None = None
) -> None:
    """The driver answered, samples arrive on time, the recorder receives them."""
    c.on_driver_parameters(driver or DRIVER)
    c.on_recorder_status(json.dumps({"receiving": {"a": 1, "b": 1, "c": 1}}), now)
    _samples(c, 0, now, clock_offset_ns)


def _samples(c: SessionController, ns: int, now: float, clock_ns: int) -> None:
    """One driver sample on each of its three topics (the encoder's last)."""
    c.on_current(ns, 0.0)
    c.on_voltage(ns, 0.0, math.nan)
    c.on_encoder(ns, 0.0, 0.0, now, clock_ns)


def test_start_up_waits_for_each_check_in_order_then_starts():
    ports = Ports()
    c = SessionController(_config(settle_s=0.5), ports)
    c.start(autostart=True, now_s=0.0)
    assert c.phase is Phase.PREPARING and [s["state"] for s in ports.status] == [
        "idle",
        "preparing",
    ]
    c.tick(0.02)
    assert ports.asked == [DRIVER_PARAMETERS]  # the driver's limits before anything moves
    assert c.start_check(0.02) is StartCheck.DRIVER
    c.on_driver_parameters(DRIVER)
    assert c.start_check(0.04) is StartCheck.SAMPLES
    c.on_encoder(0, 0.0, 0.0, 0.05, 0)
    c.on_encoder(600_000_000, 0.0, 0.0, 0.05, 600_000_000)
    # the encoder's samples arrive, the current's and the voltage's not yet (their
    # subscriptions not matched): this node would miss the session's first samples
    assert c.start_check(0.05) is StartCheck.SAMPLES
    c.on_current(600_000_000, 0.0)
    assert c.start_check(0.05) is StartCheck.SAMPLES
    c.on_voltage(600_000_000, 0.0, math.nan)
    assert c.start_check(0.05) is not StartCheck.SAMPLES
    c.on_encoder(601_000_000, 0.0, 0.0, 0.06, 801_000_000)  # 0.2 s late: a backlog
    assert c.start_check(0.06) is StartCheck.LATENCY
    c.on_encoder(602_000_000, 0.0, 0.0, 0.07, 602_000_000)
    assert c.start_check(0.07) is StartCheck.SETTLE  # on time, not yet for settle_s
    c.on_encoder(603_000_000, 0.0, 0.0, 0.58, 603_000_000)
    assert c.start_check(0.58) is StartCheck.RECORDER
    c.on_recorder_status(json.dumps({"receiving": {"a": 5, "b": 5}}), 0.58)
    assert c.start_check(0.58) is StartCheck.RECORDER  # not yet on all three topics
    c.on_recorder_status(json.dumps({"receiving": {"a": 5, "b": 5, "c": 5}}), 0.58)
    assert ports.prepared == []
    c.tick(0.58)
    assert c.phase is Phase.RUNNING and ports.status[-1]["state"] == "running"
    # the identification warms up while the session runs
    assert ports.prepared == ["seed001_110v"]
    assert ports.sent == []  # the first command answers the first sample of the session


@pytest.mark.parametrize(
    ("feed", "why"),
    [
        (lambda c: None, "no driver node 'driver_node' answered within 20 s"),
        (lambda c: c.on_driver_parameters(DRIVER), "the driver sent no samples within 20 s"),
        (
            lambda c: (c.on_driver_parameters(DRIVER), c.on_encoder(0, 0.0, 0.0, 19.9, 0)),
            "no samples on current and voltage_applied within 20 s (encoder samples arrive)",
        ),
        (
            lambda c: (
                c.on_driver_parameters(DRIVER),
                _samples(c, 0, 19.9, 0),
                c.on_recorder_status("{}", 19.9),
            ),
            "the recorder received no driver samples within 20 s",
        ),
        (
            lambda c: (c.on_driver_parameters(DRIVER), _samples(c, 0, 19.9, 0)),
            "no recorder within 20 s",
        ),
    ],
)
def test_a_session_that_cannot_start_is_refused_with_the_reason(feed, why):
    ports = Ports()
    c = SessionController(_config(exit_when_done=True), ports)
    c.start(autostart=True, now_s=0.0)
    feed(c)
    c.tick(20.1)
    assert c.finished and c.exit_code == 2 and ports.sent == [] and ports.opened == 0
    assert ports.status[-1]["state"] == "refused" and why in ports.status[-1]["detail"]


def test_safety_defaults_are_safety_config_for_limits_at_90_percent_of_the_driver():
    settings = _config().session
    session = build_session(settings, {**DRIVER, "current_limit_a": 10.0}, "s")
    lim = replace(MOTOR.limits, current_max_a=ABORT_FRACTION * 10.0,
                  speed_max_rad_s=ABORT_FRACTION * MOTOR.limits.speed_max_rad_s)  # fmt: skip
    tau = MOTOR.model.params.mechanical_time_constant_s
    assert session.monitor.config == SafetyConfig.for_limits(lim, tau)
    given = replace(settings, stall_current_a=2.0, stall_time_s=0.3, current_max_a=8.0)
    cfg = build_session(given, DRIVER, "s").monitor.config
    assert (cfg.current_max_a, cfg.stall_current_a, cfg.stall_time_s) == (8.0, 2.0, 0.3)


def test_latency_is_measured_against_the_lowest_offset_seen_and_a_late_sample_aborts():
    ports = Ports()
    c = SessionController(_config(settle_s=0.0, **{"safety.data_timeout_s": 0.5}), ports)
    c.start(autostart=True, now_s=0.0)
    offset = 5_000_000_000  # a board clock 5 s behind this host's
    _ready(c, 0.0, offset)
    c.tick(0.02)
    assert c.phase is Phase.RUNNING and c.latency.last_ns == 0
    c.on_encoder(1_000_000, 0.0, 0.0, 0.03, offset + 1_000_000 + 200_000_000)
    assert c.latency.last_ns == 200_000_000
    c.on_encoder(2_000_000, 0.0, 0.0, 0.04, offset + 2_000_000 + 600_000_000)  # > 0.5 s
    assert c.session.abort_reason is AbortReason.LOST_DRIVER_DATA
    assert "arrive 0.60 s late" in ports.status[-1]["detail"] and ports.sent[-1] == 0.0
    # the abort names its fix, in the log line and in the status (issue 24)
    remedy = "raise safety.data_timeout_s (now 0.5 s"
    assert remedy in ports.status[-1]["remedy"]
    assert any("ABORTED (lost_driver_data)" in t and remedy in t for _, t in ports.logs)


def test_commands_go_out_on_change_and_every_0_1_s_for_the_watchdog():
    ports = Ports()
    c = SessionController(_config(settle_s=0.0), ports)
    c.start(autostart=True, now_s=0.0)
    _ready(c, 0.0)
    c.tick(0.0)
    policy = c.commands
    assert policy.should_send(1.0, 0.0) and not (policy.sent(1.0, 0.0) or False)
    assert not policy.should_send(1.0, 0.05)  # unchanged, fed 0.05 s ago
    assert policy.should_send(1.0, 0.11)  # refresh for the driver's watchdog
    assert policy.should_send(2.0, 0.06)  # a change goes at once
    policy.armature_open = True
    assert policy.should_send(1.0, 0.06)  # closing the armature again


def test_confirm_safe_repeats_the_safe_command_until_the_driver_shows_it():
    ports = Ports()
    c = SessionController(_config(settle_s=0.0, safe_mode="zero", confirm_timeout_s=1.0), ports)
    c.start(autostart=True, now_s=0.0)
    _ready(c, 0.0)
    c.tick(0.0)
    c.on_encoder(1_000_000, 0.0, 0.0, 0.001, 1_000_000)
    assert c.abort_session(0.01) == (True, "session aborted, motor safe")
    assert c.confirming and ports.sent[-1] == 0.0
    n = len(ports.sent)
    c.tick(0.05)
    assert len(ports.sent) == n  # repeated only after 0.1 s
    c.tick(0.15)
    assert len(ports.sent) == n + 1 and ports.sent[-1] == 0.0
    end_ns = round(c.session.markers[-1].t_s * 1e9)
    c.on_voltage(end_ns - 1_000_000, 12.0, math.nan)  # before the abort: not the answer
    assert c.confirming
    c.on_voltage(end_ns, 0.0, math.nan)
    assert not c.confirming and c.safe_confirmed
    assert (LogLevel.INFO, "motor confirmed safe by the driver: 0 V applied") in ports.logs


def test_an_unconfirmed_safe_state_is_an_error_after_the_timeout():
    ports = Ports(service_ready=False)
    c = SessionController(_config(settle_s=0.0, safe_mode="open", confirm_timeout_s=0.5), ports)
    c.start(autostart=True, now_s=0.0)  # preparing: a stop cuts that short
    c.request_stop()
    c.tick(0.1)
    assert c.finished and c.exit_code == 130 and ports.status[-1]["state"] == "stopped"
    # no open_armature service: 0 V is the other safe state
    assert (
        ports.sent == [0.0]
        and (LogLevel.WARNING, "open_armature service not available: sent 0 V") in ports.logs
    )
    c.confirm_tick(0.7)
    assert not c.confirming and "could NOT confirm the safe state" in ports.logs[-1][1]


def test_a_stop_mid_session_aborts_it_and_exits_130():
    ports = Ports()
    c = SessionController(_config(settle_s=0.0), ports)
    c.start(autostart=True, now_s=0.0)
    _ready(c, 0.0)
    c.tick(0.0)
    c.on_encoder(1_000_000, 0.0, 0.0, 0.001, 1_000_000)
    c.request_stop()
    c.tick(0.02)
    assert c.session.abort_reason is AbortReason.INTERRUPTED
    assert c.finished and c.exit_code == 130 and ports.status[-1]["reason"] == "interrupted"


def test_a_stop_while_idle_is_a_clean_exit():
    ports = Ports()
    c = SessionController(_config(), ports)
    c.start(autostart=False, now_s=0.0)
    c.request_stop()
    c.tick(0.1)
    assert c.finished and c.exit_code == 0 and ports.sent == [0.0]  # safe all the same


def test_a_stop_while_idle_with_the_driver_stopping_too_ends_without_an_error():
    """ros2 launch stops every node at once: the driver stops publishing (it makes its
    motor safe itself), so an idle stop's confirmation ends at once, not in an error
    after confirm_timeout_s (launch escalated to SIGTERM at its 5 s)."""
    ports = Ports()
    c = SessionController(_config(safe_mode="zero", confirm_timeout_s=3.0), ports)
    c.start(autostart=False, now_s=0.0)
    c.on_encoder(1_000_000, 0.0, 0.0, 1.0, 1_000_000)  # the driver publishes...
    c.request_stop()
    c.tick(1.1)
    assert c.confirming and ports.logs[-1][0] == LogLevel.INFO
    c.confirm_tick(1.3)  # ... and stops: not yet quiet for long
    assert c.confirming
    c.confirm_tick(1.6)
    assert not c.confirming and not c.safe_confirmed
    assert ports.logs[-1] == (
        LogLevel.INFO,
        "the driver stopped too (it makes the motor safe when it stops)",
    )
    assert c.finished and c.exit_code == 0
    assert not [t for level, t in ports.logs if level == LogLevel.ERROR]
    # a driver still publishing is waited for (and confirms) as before
    ports = Ports()
    c = SessionController(_config(safe_mode="zero", confirm_timeout_s=3.0), ports)
    c.start(autostart=False, now_s=0.0)
    c.request_stop()
    c.tick(1.0)
    for k in range(1, 10):
        c.on_encoder(k * 100_000_000, 0.0, 0.0, 1.0 + 0.1 * k, 0)
        c.confirm_tick(1.0 + 0.1 * k)
    assert c.confirming
    c.on_voltage(900_000_000, 0.0, math.nan)
    assert c.safe_confirmed


def test_a_lost_recorder_aborts_the_running_session():
    ports = Ports()
    c = SessionController(_config(settle_s=0.0, peer_timeout_s=0.5), ports)
    c.start(autostart=True, now_s=0.0)
    _ready(c, 0.0)
    c.tick(0.0)
    for k in range(1, 31):  # samples keep coming; the recorder's heartbeat stops
        c.on_encoder(k * 20_000_000, 0.0, 0.0, k * 0.02, k * 20_000_000)
        c.tick(k * 0.02)
    assert c.session.abort_reason is AbortReason.PEER_CRASHED
    assert ports.status[-1] == {
        "schema_version": 1,
        "state": "aborted",
        "session": c.session.name,
        "reason": "peer_crashed",
        "detail": "recorder heartbeat lost: recorder gone",
        "remedy": "if the recorder is only slow, raise peer_timeout_s (now 0.5 s)",
        "bag": "",
    }


def _closed_loop(
    cfg: ControllerConfig, driver: dict | None = None, bag_dir: str = ""
) -> tuple[SessionController, Ports]:
    """A whole session closed around the simulated plant, up to the identification;
    with ``bag_dir`` the recorder reports the bag ``<bag_dir>/<session>`` (as given)."""
    ports = Ports()
    c = SessionController(cfg, ports)
    c.start(autostart=True, now_s=0.0)
    _ready(c, 0.0, driver=driver)
    c.tick(0.0)
    plant = Plant(MOTOR.model, DT, substeps=4)
    applied = 0.0
    for k in range(200_000):
        now = k * DT
        ns = k * 1_000_000
        v = math.nan if c.commands.armature_open else applied
        c.on_current(ns, plant.current_a)
        c.on_voltage(ns, v, math.nan)
        c.on_encoder(ns, plant.position_rad, plant.speed_rad_s, now, ns)
        if k % 20 == 0:
            c.tick(now)
        if k % 200 == 0:  # the recorder's heartbeat
            beat: dict[str, Any] = {"receiving": {"a": ns, "b": ns, "c": ns}}
            if bag_dir and c.session is not None:
                beat |= {"session": c.session.name, "path": f"{bag_dir}/{c.session.name}"}
            c.on_recorder_status(json.dumps(beat), now)
        if ports.sent:
            applied = ports.sent[-1]
        plant.step(None if c.commands.armature_open else applied)
        if c.phase is Phase.IDENTIFYING:
            break
    assert ports.jobs, [s["state"] for s in ports.status]
    return c, ports


def test_a_whole_session_closed_around_the_plant_hands_every_sample_to_the_identification():
    c, ports = _closed_loop(_config(settle_s=0.0, safe_mode="zero", exit_when_done=True))
    job = ports.jobs[0]
    assert job.exports is None  # export_models is off by default
    events = [m["event"] for m in ports.markers]
    assert events[0] == "session_start" and events[-1] == "session_end"
    assert (
        job.samples.encoder_ns.size == job.samples.current_ns.size == job.samples.voltage_ns.size
    )
    start_ns, end_ns = (
        round(m.t_s * 1e9) for m in (job.samples.markers[0], job.samples.markers[-1])
    )
    inside = (job.samples.encoder_ns >= start_ns) & (job.samples.encoder_ns < end_ns)
    assert inside.sum() == (end_ns - start_ns) // 1_000_000  # every sample of the session
    c.on_identified(IdentificationOutcome(json_text="{}", table="t", n_samples=5, output_dir="o"))
    assert ports.results == ["{}"] and ports.status[-1]["state"] == "done"
    c.tick(1e6)
    assert c.finished and c.exit_code == 0


def test_unknown_parameters_of_the_node_are_refused_in_one_line():
    with pytest.raises(Exception, match="parameter fix"):
        _config(fix=["R=-1"])
    with pytest.raises(Exception, match="parameters sequence"):
        _config(**{"sequence.staircase_levels": 1})
    assert _config().session.safe_mode is SafeMode.ZERO
    assert isinstance(_config().session.steady, SteadyStateConfig)
    assert isinstance(_config().session.sequence, SequenceConfig)
    assert isinstance(_config().session, SessionSettings)


def test_exports_are_written_beside_the_results_and_a_failed_one_is_one_line(
    tmp_path, monkeypatch
):
    """export_models: the identification job also writes the identified motor's MJCF,
    URDF, ros2_control and gains files for the driver's joint; a failure is a warning
    and a field of the result, never a failed identification. The job names its bag by
    absolute path, whatever path the recorder (started in the same folder) gave."""
    from pmdc_ident.process.identify_call import run_identification_job, write_session_exports

    monkeypatch.chdir(tmp_path)
    cfg = _config(settle_s=0.0, export_models=True, export_reduction=3.0)
    driver = {**DRIVER, "joint_name": "left_wheel_joint"}
    c, ports = _closed_loop(cfg, driver=driver, bag_dir="sessions")
    job = ports.jobs[0]
    # the gains' rate is the session's (the driver's 1 kHz), the joint the driver's
    assert job.exports == ExportRequest(
        reduction=3.0, sample_rate_hz=1000.0, joint="left_wheel_joint"
    )
    bag = tmp_path / "sessions" / c.session.name
    assert job.source == str(bag) and job.output_dir == bag  # absolute (issue 24)
    out = run_identification_job(replace(job, output_dir=tmp_path / "ok"))
    assert not out.error, out.error
    names = ["identified" + s for s in EXPORT_FILES]
    assert json.loads(out.json_text)["exports"] == {"files": names, "error": None}
    assert json.loads((tmp_path / "ok" / "parameters.json").read_text()) == json.loads(
        out.json_text
    )
    mjcf, urdf_text, control, gains = ((tmp_path / "ok" / n).read_text() for n in names)
    assert ET.fromstring(mjcf).tag == "mujoco"
    assert ET.fromstring(urdf_text).find("joint/dynamics") is not None
    assert ET.fromstring(urdf_text).find("joint").get("name") == "left_wheel_joint"
    assert (
        "left_wheel_joint"
        in yaml.safe_load(control)["left_wheel_joint_speed_pid"]["ros__parameters"]["dof_names"]
    )
    assert yaml.safe_load(control) and yaml.safe_load(gains)["verification"]
    assert (
        LogLevel.INFO,
        f"exports written to {tmp_path / 'ok'}: {', '.join(names)}",
    ) in out.notes
    # a speed loop the 1 kHz current loop cannot carry: no files, one warning, no raise
    notes: list[tuple[LogLevel, str]] = []
    spec = load_motor(str(tmp_path / "ok" / "parameters.yaml"))
    bad = replace(job.exports, speed_bandwidth_hz=400.0)
    said = write_session_exports(spec, tmp_path / "bad", bad, notes)
    assert said["files"] == [] and "speed bandwidth 400 Hz" in said["error"], said
    assert notes == [(LogLevel.WARNING, f"exports not written: {said['error']}")]
    assert not (tmp_path / "bad").exists()


def test_a_backlog_drained_one_topic_first_is_judged_with_each_samples_own_current():
    # a node held up by the host drains its encoder queue before its current queue:
    # each encoder sample waits for the current of its stamp, so a locked rotor's
    # stall is called stall_time_s after the current rose, not on a stale 0 A
    ports = Ports()
    c = SessionController(
        _config(settle_s=0.0, **{"safety.stall_current_a": 5.0, "safety.stall_time_s": 0.2}),
        ports,
    )
    c.start(autostart=True, now_s=0.0)
    _ready(c, 0.0)
    c.tick(0.02)
    assert c.phase is Phase.RUNNING
    stamps = [k * 1_000_000 for k in range(1, 400)]
    for ns in stamps:  # the encoder's backlog first (all within CURRENT_WAIT_S)
        c.on_encoder(ns, 0.0, 0.0, 0.05, ns)
    assert c.session.abort_reason is None
    for ns in stamps:  # the applied voltage's next (each sample waits for both)
        c.on_voltage(ns, 6.0, math.nan)
    assert c.session.abort_reason is None
    for ns in stamps:  # then the current's: 12 A from the first sample on
        c.on_current(ns, 12.0)
        if c.session.abort_reason is not None:
            break
    assert c.session.abort_reason is AbortReason.STALL
    (abort,) = [m for m in ports.markers if m["event"] == "abort"]
    assert 0.2 <= abort["t_s"] < 0.21, abort  # 0.2 s after the first sample's 12 A


def test_default_session_names_are_unique_for_motors_started_in_the_same_second():
    """Two wheels (two namespaces) started at once, and two sessions in one namespace:
    every default session name differs, and says which motor it is (issue 24)."""
    names = []
    for namespace in ("/left_wheel", "/right_wheel", "/left_wheel", "/"):
        values = {**IDENTIFICATION.defaults(), "motor": "seed001_110v", **SHORT}
        values["settle_s"] = 0.0
        c = SessionController(controller_config(values, namespace=namespace), Ports())
        c.start(autostart=True, now_s=0.0)
        _ready(c, 0.0)
        c.tick(0.02)
        assert c.phase is Phase.RUNNING
        names.append(c.session.name)
    assert len(set(names)) == 4, names
    assert re.fullmatch(r"session_\d{8}_\d{6}_left_wheel_[0-9a-f]{6}", names[0]), names
    assert re.fullmatch(r"session_\d{8}_\d{6}_right_wheel_[0-9a-f]{6}", names[1]), names
    assert re.fullmatch(r"session_\d{8}_\d{6}_[0-9a-f]{6}", names[3]), names


def test_a_staircase_level_is_not_judged_settled_while_the_driver_has_not_applied_it():
    """Commands reach the driver late (a loaded host): for a second it keeps the armature
    open, the rotor rests, and this node drains each backlog encoder first, the applied
    voltage after. The level must not end as 'settled' on the rotor at rest (an emulated
    board's session under load ended both levels so, 5,700 samples of its 8,000)."""
    ports = Ports()
    c = SessionController(_config(settle_s=0.0), ports)
    c.start(autostart=True, now_s=0.0)
    _ready(c, 0.0)
    c.tick(0.02)
    assert c.phase is Phase.RUNNING
    for batch in range(10):  # 1 s in batches of 100 ms: encoder and current, then voltage
        stamps = [(batch * 100 + k + 1) * 1_000_000 for k in range(100)]
        now = 0.02 + (batch + 1) * 0.1
        for ns in stamps:
            c.on_current(ns, 0.0)
            c.on_encoder(ns, 0.0, 0.0, now, ns)
        for ns in stamps:
            c.on_voltage(ns, math.nan, math.nan)
        c.tick(now)
    assert c.session.abort_reason is None
    assert not [m for m in ports.markers if m["event"] == "end"], ports.markers


def test_current_and_voltage_handed_over_before_the_session_runs_are_its_own():
    # a host draining its queues one topic after another hands over current and voltage
    # samples stamped after the last encoder sample it has seen before the session runs:
    # the session starts at the next encoder sample, so they are the session's first
    ports = Ports()
    c = SessionController(_config(settle_s=0.0), ports)
    c.start(autostart=True, now_s=0.0)
    _ready(c, 0.0)  # one sample of each topic at stamp 0
    ahead = [k * 1_000_000 for k in range(1, 301)]
    for ns in ahead:
        c.on_current(ns, 1.0)
        c.on_voltage(ns, 0.0, math.nan)
    c.tick(0.02)
    assert c.phase is Phase.RUNNING
    for ns in ahead:
        c.on_encoder(ns, 0.0, 0.0, 0.05, ns)
    rec = c.recording
    assert rec.current.n == rec.voltage.n == rec.encoder.n == len(ahead)
    assert np.array_equal(rec.current.stamps(), rec.encoder.stamps())
    assert np.array_equal(rec.voltage.stamps(), rec.encoder.stamps())
