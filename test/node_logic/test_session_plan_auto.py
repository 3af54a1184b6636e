"""The identification node's ``plan`` parameter without DDS (issue 25): a sequential
session (``plan: auto``) closed around the simulated plant, its jobs run by the worker's
own function; a plan CSV; a travel range that aborts. ROS-free and fast."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pmdc_ident.core.enums import AbortReason
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.model import Plant
from pmdc_ident.core.motors import MotorSpec, load_motor
from pmdc_ident.core.safety import SafetyConfig
from pmdc_ident.node_logic.session.controller import ControllerConfig, Phase, SessionController
from pmdc_ident.node_logic.session.ports import IdentificationJob
from pmdc_ident.node_logic.session.recording import Recording
from pmdc_ident.node_logic.session.remedy import abort_remedy
from pmdc_ident.node_logic.session.sequential import DesignJob, PlanSetting
from pmdc_ident.process.identify_call import run_design_job
from pmdc_ident.process.parameter_tables import IDENTIFICATION
from pmdc_ident.process.settings import controller_config

DT = 1e-3
MOTOR = load_motor("seed001_110v")
DRIVER = {"voltage_limit_v": 110.0, "current_limit_a": 0.0, "speed_limit_rad_s": 0.0,
          "motor": "seed001_110v", "rate_hz": 1000.0}  # fmt: skip
WORKER_LAG = 300  # driver samples between a job and its outcome (a worker's fit time)


class Ports:
    def __init__(self) -> None:
        self.sent: list[float] = []
        self.markers: list[dict] = []
        self.status: list[dict] = []
        self.logs: list[tuple[str, str]] = []
        self.jobs: list[IdentificationJob] = []
        self.design_jobs: list[DesignJob] = []
        self.opened = 0

    def send_voltage(self, voltage_v: float) -> None:
        self.sent.append(voltage_v)

    def open_armature(self) -> bool:
        self.opened += 1
        return True

    def publish_marker(self, text: str) -> None:
        self.markers.append(json.loads(text))

    def publish_progress(self, text: str) -> None:
        pass

    def publish_status(self, text: str) -> None:
        self.status.append(json.loads(text))

    def publish_result(self, text: str) -> None:
        pass

    def request_driver_parameters(self, names: tuple[str, ...]) -> bool:
        return True

    def prepare_identification(self, nominal: MotorSpec) -> None:
        pass

    def start_design(self, job: object) -> None:
        assert isinstance(job, DesignJob)
        self.design_jobs.append(job)

    def start_identification(self, job: IdentificationJob) -> None:
        self.jobs.append(job)

    def log(self, level: str, text: str) -> None:
        self.logs.append((level, text))


def _config(**overrides: Any) -> ControllerConfig:
    return controller_config(
        {**IDENTIFICATION.defaults(), "motor": "seed001_110v", "settle_s": 0.0, **overrides}
    )


def _closed_loop(cfg: ControllerConfig, motor=MOTOR, start_rad: float = 0.0):  # type: ignore[no-untyped-def]
    """A session around the plant; design jobs answered WORKER_LAG samples later by the
    worker's own function (what the node's child process runs)."""
    ports = Ports()
    c = SessionController(cfg, ports)
    c.start(autostart=True, now_s=0.0)
    c.on_driver_parameters(DRIVER)
    c.on_recorder_status(json.dumps({"receiving": {"a": 1, "b": 1, "c": 1}}), 0.0)
    plant = Plant(motor.model, DT, substeps=4)
    plant._state[2] = start_rad  # noqa: SLF001 - the joint rests there
    applied, pending, trace = 0.0, [], []
    for k in range(60_000):
        now, ns = k * DT, k * 1_000_000
        v = math.nan if c.commands.armature_open else applied
        c.on_current(ns, plant.current_a)
        c.on_voltage(ns, v, math.nan)
        c.on_encoder(ns, plant.position_rad, plant.speed_rad_s, now, ns)
        trace.append((now, plant.position_rad, plant.current_a))
        if k % 20 == 0:
            c.tick(now)
            c.on_recorder_status(json.dumps({"receiving": {"a": ns, "b": ns, "c": ns}}), now)
        while len(ports.design_jobs) > len(pending):
            job = ports.design_jobs[len(pending)]
            pending.append((k + WORKER_LAG, run_design_job(job)))
        for due, out in pending:
            if due == k:
                c.on_design(out, now)
        if ports.sent:
            applied = ports.sent[-1]
        plant.step(None if c.commands.armature_open else applied)
        if c.phase in (Phase.IDENTIFYING, Phase.FINISHED):
            break
    return c, ports, np.array(trace)


def test_plan_auto_runs_the_pretest_designs_refits_and_stops_at_the_target():
    c, ports, _ = _closed_loop(_config(plan="auto"))
    assert ports.jobs, ports.logs[-5:]
    job = ports.jobs[0]
    report = job.extra["experiment_design"]  # type: ignore[index]
    labels = [m["label"] for m in ports.markers if m["event"] == "start"]
    assert labels[:2] == ["pretest_up", "pretest_down"]
    assert len(labels) > 2 and report["designs"] >= 1
    actions = [r["action"] for r in report["rounds"]]
    assert actions[0] == "extend" and actions[-1] == "stop", report["rounds"]
    assert report["rounds"][-1]["message"].startswith("target met"), report["rounds"][-1]
    # the session ended on the design's word, not on a timeout: within 10 % of the plan
    # (or earlier, when a re-fit met the target before the plan's end)
    assert report["motor_s"] <= 1.1 * report["planned_s"], report
    events = [m["event"] for m in ports.markers]
    assert events[0] == "session_start" and events[-1] == "session_end"
    assert "abort" not in events
    # the final identification gets every segment, the designed ones included
    from pmdc_ident.process.identify_call import run_identification_job

    assert {m.label for m in job.samples.markers if m.label} >= set(labels)
    del run_identification_job


def test_a_plan_csv_runs_as_written(tmp_path: Path):
    from pmdc_ident.core.design import Prior, plan_csv_text, plan_experiment

    prior = Prior.from_spec(MOTOR)
    designed = plan_experiment(prior, MOTOR.limits, DT)
    path = tmp_path / "plan.csv"
    path.write_text(plan_csv_text(designed.plan))
    c, ports, _ = _closed_loop(_config(plan=str(path)))
    labels = [m["label"] for m in ports.markers if m["event"] == "start"]
    assert labels == [s.label for s in designed.plan.segments]
    assert ports.jobs and ports.jobs[0].extra is None


def test_a_plan_csv_at_another_rate_is_refused_before_anything_moves(tmp_path: Path):
    from pmdc_ident.core.design import Prior, plan_csv_text, plan_experiment

    designed = plan_experiment(Prior.from_spec(MOTOR), MOTOR.limits, 2e-3)
    path = tmp_path / "plan.csv"
    path.write_text(plan_csv_text(designed.plan))
    ports = Ports()
    c = SessionController(_config(plan=str(path)), ports)
    c.start(autostart=True, now_s=0.0)
    c.on_driver_parameters(DRIVER)
    c.on_recorder_status(json.dumps({"receiving": {"a": 1, "b": 1, "c": 1}}), 0.0)
    c.on_current(0, 0.0)
    c.on_voltage(0, 0.0, math.nan)
    c.on_encoder(0, 0.0, 0.0, 0.0, 0)
    c.tick(0.0)
    assert ports.status[-1]["state"] == "refused"
    assert "500 Hz" in ports.status[-1]["detail"] and not ports.sent


def test_the_plan_parameters_are_checked_in_one_line():
    with pytest.raises(PmdcError, match="plan"):
        _config(plan="sometimes")
    with pytest.raises(PmdcError, match="travel"):
        _config(**{"plan_travel_rad": [2.0, -2.0]})
    with pytest.raises(PmdcError, match="target"):
        _config(**{"plan_target": "R=2x"})
    assert (
        PlanSetting.from_values({"plan": "auto", "plan_travel_rad": [0.0, 0.0]}).travel_rad is None
    )


def test_a_travel_range_aborts_when_the_measured_position_leaves_it():
    """A joint that runs off its range (a default plan on a motor that turns freely) is
    stopped by the travel rule, the motor made safe."""
    c, ports, trace = _closed_loop(
        _config(plan=str(_default_csv()), **{"plan_travel_rad": [-2.0, 2.0]})
    )
    assert ports.status[-1]["state"] == "aborted"
    assert ports.status[-1]["reason"] == AbortReason.OUT_OF_TRAVEL.value
    assert ports.sent[-1] == 0.0
    # it tripped on the first sample outside: at most one sample of travel beyond the end
    over = trace[np.abs(trace[:, 1]) > 2.0]
    assert over.size and abs(over[0, 1]) < 2.0 + 0.2
    # every sample arrived on time here: the plan, not the host, is what to look at
    assert "commands were on time" in ports.status[-1]["remedy"], ports.status[-1]


def test_an_abort_out_of_travel_names_a_host_that_fell_behind_the_plans_command_delay():
    """Samples that reached the node later than the plan's command delay in the last
    seconds before a travel abort: the line names the lateness and the parameter."""
    rec = Recording()
    for k in range(3000):  # 3 s at 1 kHz; the last 0.5 s arrives 0.4 s late
        rec.encoder.append(k * 1_000_000, 0.0, 0.0)
        rec.latency.append(400_000_000 if k >= 2500 else 2_000_000)
    assert rec.max_latency_s(1_000_000_000) == pytest.approx(0.4)
    assert rec.max_latency_s(0) == pytest.approx(0.4)
    assert rec.max_latency_s(2_600_000_000) == pytest.approx(0.4)
    safety = SafetyConfig(current_max_a=10.0, speed_max_rad_s=100.0)
    text = abort_remedy(AbortReason.OUT_OF_TRAVEL, safety, 2.0, late_s=0.4, command_delay_s=0.15)
    assert "0.40 s late" in text and "plan_command_delay_s (now 0.15 s)" in text
    assert "commands were on time" in abort_remedy(
        AbortReason.OUT_OF_TRAVEL, safety, 2.0, late_s=0.01, command_delay_s=0.15
    )


def _default_csv() -> Path:
    import tempfile

    from pmdc_ident.core.design import plan_csv_text
    from pmdc_ident.core.excitation import plan_for_motor

    path = Path(tempfile.mkdtemp()) / "default.csv"
    path.write_text(plan_csv_text(plan_for_motor(MOTOR, DT)))
    return path


@pytest.mark.parametrize("kind", ["auto", "csv"])
def test_a_designed_plan_waits_until_the_node_has_caught_up_with_the_driver(kind: str):
    # making the session (the pre-test's planning) holds the node up: the samples it then
    # drains arrive late, and a square wave started on them would reach the driver late;
    # a plan CSV (travel-limited, fast switching) is held the same way
    plan, first = ("auto", "pretest_up") if kind == "auto" else (str(_default_csv()), None)
    c = SessionController(_config(plan=plan), Ports())
    ports = c.ports
    c.start(autostart=True, now_s=0.0)
    c.on_driver_parameters(DRIVER)
    c.on_recorder_status(json.dumps({"receiving": {"a": 1, "b": 1, "c": 1}}), 0.0)

    def sample(k: int, lag_s: float) -> None:
        ns = k * 1_000_000
        now = k * DT + lag_s
        c.on_current(ns, 0.0)
        c.on_voltage(ns, 0.0, math.nan)
        c.on_encoder(ns, 0.0, 0.0, now, ns + round(lag_s * 1e9))
        if k % 20 == 0:
            c.tick(now)
            c.on_recorder_status(json.dumps({"receiving": {"a": ns, "b": ns, "c": ns}}), now)

    k = 0
    while c.phase is not Phase.RUNNING and k < 5000:
        sample(k, 0.0)
        k += 1
    assert c.phase is Phase.RUNNING and c.session.awaiting_release
    for _ in range(500):  # a backlog: half a second behind the driver
        sample(k, 0.5)
        k += 1
    assert c.session.awaiting_release, "the pre-test started on samples 0.5 s late"
    assert not [m for m in ports.markers if m["event"] == "start"]
    for _ in range(300):  # caught up
        sample(k, 0.0)
        k += 1
    assert not c.session.awaiting_release
    first = first or c.session.plan.segments[0].label
    assert [m["label"] for m in ports.markers if m["event"] == "start"][0] == first


def _holding_joint() -> tuple[SessionController, Ports]:
    """A ``plan: auto`` session on a joint, its pre-test run out: the session holds."""
    c = SessionController(_config(plan="auto", **{"plan_travel_rad": [-2.0, 2.0]}), Ports())
    c.start(autostart=True, now_s=0.0)
    c.on_driver_parameters(DRIVER)
    c.on_recorder_status(json.dumps({"receiving": {"a": 1, "b": 1, "c": 1}}), 0.0)
    k = 0
    while not (c.session is not None and c.session.holding and c.design_pending) and k < 20_000:
        ns = k * 1_000_000
        c.on_current(ns, 0.0)
        c.on_voltage(ns, c.ports.sent[-1] if c.ports.sent else 0.0, math.nan)
        c.on_encoder(ns, 0.25, 0.0, k * DT, ns)
        if k % 20 == 0:
            c.tick(k * DT)
            c.on_recorder_status(json.dumps({"receiving": {"a": ns, "b": ns, "c": ns}}), k * DT)
        k += 1
    assert c.session is not None and c.session.holding and c.design_pending
    return c, c.ports  # type: ignore[return-value]


def test_an_extension_designed_for_another_start_is_re_designed_then_refused():
    """A joint's extension is designed from where the worker predicted the rotor would
    rest under the hold; one that finds the joint elsewhere would carry the offset into
    its travel margin: it is dropped and designed again from the measured position, and
    after three such the session ends without it (never an extension from a wrong
    start)."""
    from pmdc_ident.core.design.sequential import start_tolerance_rad
    from pmdc_ident.core.excitation import PlannedSegment
    from pmdc_ident.node_logic.session.sequential import DesignOutcome

    c, ports = _holding_joint()
    tol = start_tolerance_rad((-2.0, 2.0))
    seg = (PlannedSegment("level_03", np.full(200, 1.0)),)
    design = c.design
    # within the tolerance: extended
    c.on_design(DesignOutcome("extend", seg, design, "ok", start_rad=0.25 + 0.9 * tol), 1.0)
    assert not c.session.holding and c.session.plan_labels[-1] == "level_03"

    c, ports = _holding_joint()
    for k in range(100):  # still braking: 1 rad/s
        ns = (20_000 + k) * 1_000_000
        c.on_encoder(ns, 0.25 + 1e-3 * k, 1.0, ns * 1e-9, ns)
    c.on_design(DesignOutcome("extend", seg, object(), "x", start_rad=0.3), 1.0)
    assert c.session.holding and "still moving" in ports.logs[-1][1], ports.logs[-1]

    c, ports = _holding_joint()
    before = c.design
    for n in range(3):
        c.on_design(DesignOutcome("extend", seg, object(), "x", start_rad=0.25 + 2 * tol), 1.0)
        assert c.session.holding and c.session.active
        assert c.design is before  # the dropped design's state is not kept
        assert "re-designing from there" in ports.logs[-1][1]
        c.tick(1.0 + n)  # the hold is re-fitted: a new job from the joint's position
        assert c.design_pending
    c.on_design(DesignOutcome("extend", seg, object(), "x", start_rad=0.25 + 2 * tol), 5.0)
    assert not c.session.active or c.session.state.name != "RUNNING"
    assert "level_03" not in c.session.plan_labels
    assert any("plan not extended" in t and "0.25 rad" in t for _, t in ports.logs), ports.logs


def _pretest_job(cfg: ControllerConfig) -> DesignJob:
    """The worker's first job of a ``plan: auto`` session: its pre-test, run on the
    simulated motor (noise of its motor file) and recorded as the node would."""
    from pmdc_ident.core.excitation import apply_sensors
    from pmdc_ident.core.markers import Marker, MarkerEvent
    from pmdc_ident.core.model import simulate
    from pmdc_ident.core.samples import DriverSamples
    from pmdc_ident.node_logic.session.sequential import build_planned_session

    _, design = build_planned_session(cfg.session, cfg.plan, DRIVER, "lag", 0.0)
    plan = design.pretest
    v = np.concatenate([s.voltage for s in plan.segments])
    sim = simulate(MOTOR.model, v, DT)
    i, w, th = apply_sensors(
        sim.current, sim.speed, sim.position, MOTOR.sensors, np.random.default_rng(3)
    )
    ns = (np.arange(v.size) + 1000) * 1_000_000
    markers, t = [Marker(MarkerEvent.SESSION_START, "", 1.0, "lag")], 1.0
    for s in plan.segments:
        markers.append(Marker(MarkerEvent.START, s.label, t, "lag"))
        t += s.voltage.size * DT
        markers.append(Marker(MarkerEvent.END, s.label, t, "lag"))
    samples = DriverSamples(ns, i, ns, th, w, ns, v, None, markers=tuple(markers))
    return DesignJob(samples, "lag", "lag", design, plan_done=True, position_rad=float(th[-1]))


def test_the_current_lag_parameter_reaches_the_design():
    """``plan_current_lag_s`` is the rig's lag every design of the session counts: the
    1 ms lag of a slow anti-alias filter biases this motor's L (L/R 34 ms) by up to 3 %,
    beyond its 1 % target, so the design drops L and says which parameter to give; on the
    same pre-test a chain known to have no lag (0) meets the target, L included. Negative
    (the default): not known."""
    assert PlanSetting.from_values(IDENTIFICATION.defaults()).current_lag_s is None
    with pytest.raises(PmdcError, match="plan_current_lag_s"):
        PlanSetting.from_values({"plan_current_lag_s": math.nan})
    lagged = run_design_job(_pretest_job(_config(plan="auto", plan_current_lag_s=1e-3)))
    assert not lagged.error, lagged.message
    assert lagged.design.nominal.noise.current_lag_s == 1e-3
    why = lagged.design.dropped.get("L", "")
    assert "1e+03 us late" in why and "parameter plan_current_lag_s" in why, why
    known = run_design_job(_pretest_job(_config(plan="auto", plan_current_lag_s=0.0)))
    # the same pre-test, a chain without lag: its L (known to 0.04 %) meets the target
    assert known.message.startswith("target met") and "L " in known.message, known.message
    assert "L" not in known.design.dropped, known.design.dropped
