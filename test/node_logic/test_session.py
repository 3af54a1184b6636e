"""The ROS-free session state machine, closed around the simulated plant.

The loop reproduces what happens over DDS: the session sees driver sample k and
its command reaches the plant ``latency`` samples later.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace

import numpy as np
import pytest

from pmdc_ident.core.enums import SafeMode
from pmdc_ident.core.excitation import SequenceConfig, TestPlan, plan_for_motor
from pmdc_ident.core.model import Plant
from pmdc_ident.core.motors import Limits, load_motor
from pmdc_ident.node_logic.session import (
    AbortReason,
    Marker,
    MarkerEvent,
    SafetyConfig,
    Session,
    SessionState,
    SteadyStateConfig,
    check_plan,
)

DT = 1e-3
SHORT = SequenceConfig(
    staircase_levels=3,
    staircase_hold_tau=5.0,
    step_hold_tau=5.0,
    sweep_duration_tau=20.0,
    coast_spinup_tau=4.0,
)


def _run(
    session: Session,
    model,
    *,
    latency: int = 2,
    max_samples: int = 200_000,
    noise=None,
    drop: float = 0.0,
    open_for: int = 0,
    tell_applied: bool = False,
):
    """Close the loop; returns per-sample arrays (t, applied V, i, w). ``open_for``:
    the armature stays open that many samples from the start (commands that reach the
    driver late); ``tell_applied``: the session is told what the driver applies."""
    plant = Plant(model, DT, substeps=4)
    pipe: deque[float] = deque([0.0] * latency)
    applied_v = 0.0
    rows = []
    rng = np.random.default_rng(1)
    session.start()
    for k in range(max_samples):
        if k < open_for:
            applied_v = math.nan
        t = plant.time_s
        i, w = plant.current_a, plant.speed_rad_s
        if noise:
            i += rng.normal(0, noise[0])
            w += rng.normal(0, noise[1])
        if drop and rng.random() < drop and session.state is SessionState.RUNNING:
            pipe.append(pipe[-1] if pipe else applied_v)  # sample lost: no new command
        else:
            told = applied_v if tell_applied else None
            step = session.on_sample(t, i, w, applied_v=told)
            pipe.append(step.command.voltage_v if step.command else applied_v)
        applied_v = pipe.popleft()
        if k < open_for:
            applied_v = math.nan
        rows.append((t, applied_v, i, w))
        plant.step(None if math.isnan(applied_v) else applied_v)
        if not session.active:
            break
    return np.array(rows)


def test_short_sequence_runs_every_segment_in_order_with_markers_on_the_driver_clock():
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, DT, SHORT)
    safety = SafetyConfig.for_limits(spec.limits, spec.model.params.mechanical_time_constant_s)
    s = Session(plan, safety, tau_m_s=spec.model.params.mechanical_time_constant_s)
    _run(s, spec.model, noise=(0.01, 0.05))
    assert s.state is SessionState.DONE
    starts = [m.label for m in s.markers if m.event is MarkerEvent.START]
    ends = [m.label for m in s.markers if m.event is MarkerEvent.END]
    assert starts == ends == [p.label for p in plan.segments]
    assert s.markers[0].event is MarkerEvent.SESSION_START
    assert s.markers[-1].event is MarkerEvent.SESSION_END
    # markers sit on the sample grid, each segment starts where the previous ended
    pairs = list(zip(s.markers[1:-1:2], s.markers[2:-1:2], strict=True))
    for start, end in pairs:
        assert start.event is MarkerEvent.START and end.event is MarkerEvent.END
        n = round((end.t_s - start.t_s) / DT)
        assert abs((end.t_s - start.t_s) / DT - n) < 1e-6
        assert n == s.held_samples[start.label]
    for (_, e1), (s2, _) in zip(pairs[:-1], pairs[1:], strict=True):
        assert s2.t_s == e1.t_s
    # non-staircase segments run exactly their planned length
    for seg in plan.segments:
        if not seg.label.startswith("staircase"):
            assert s.held_samples[seg.label] == seg.voltage.size
    assert s.progress().total_fraction == 1.0


def test_staircase_waits_for_real_steady_state_when_the_nominal_tau_is_too_short():
    spec = load_motor("seed001_110v")
    tau = spec.model.params.mechanical_time_constant_s  # ~50 ms
    # Nominal tau four times too short: a fixed 5 tau_nominal hold would end at
    # 1.25 true tau (speed at 71 % of final). The detector must hold on.
    cfg = SequenceConfig(staircase_levels=2, steps=False, sweep=False, coast=False)
    plan = plan_for_motor(replace(spec), DT, cfg)
    plan = TestPlan(
        tuple(replace(p, voltage=p.voltage[: int(5 * tau / 4 / DT)]) for p in plan.segments), DT
    )
    safety = SafetyConfig.for_limits(spec.limits, tau)
    steady = SteadyStateConfig(window_s=tau, timeout_factor=20.0)
    s = Session(plan, safety, tau_m_s=tau / 4, steady=steady)
    rows = _run(s, spec.model, noise=(0.01, 0.05))
    assert s.state is SessionState.DONE
    assert all(s.settled.values())
    nominal = plan.segments[0].voltage.size
    held = s.held_samples["staircase_01"]
    assert held > 2 * nominal  # held past the fixed time
    # at the moment it moved on, speed is within 1 % of the true steady state
    end = next(m for m in s.markers if m.event is MarkerEvent.END)
    k = int(round(end.t_s / DT)) - 1
    _, w_ss = spec.model.params.steady_state(plan.segments[0].voltage[0])
    assert rows[k, 3] == pytest.approx(w_ss, rel=0.01)


def test_a_staircase_level_applied_late_is_judged_only_once_the_driver_applies_it():
    """Commands that reach the driver late (a loaded host, a command topic matched late)
    leave the armature open: the rotor rests, 'steady', and the level used to end at its
    minimum hold without ever being applied (an emulated board's session under load ran
    5,700 samples of its 8,000, both staircase levels at rest). Told what the driver
    applies, the session holds each level until it is applied and settled."""
    spec = load_motor("seed001_110v")
    tau = spec.model.params.mechanical_time_constant_s
    cfg = SequenceConfig(staircase_levels=2, steps=False, sweep=False, coast=False)
    plan = plan_for_motor(spec, DT, cfg)
    safety = SafetyConfig.for_limits(spec.limits, tau)
    late = plan.segments[0].voltage.size * 3 // 2  # open past the level's nominal hold
    told = Session(plan, safety, tau_m_s=tau)
    rows = _run(told, spec.model, noise=(0.01, 0.05), open_for=late, tell_applied=True)
    assert told.state is SessionState.DONE and all(told.settled.values())
    assert told.held_samples["staircase_01"] > late
    for label, seg in zip(("staircase_01", "staircase_02"), plan.segments, strict=True):
        end = next(m for m in told.markers if m.event is MarkerEvent.END and m.label == label)
        _, w_ss = spec.model.params.steady_state(seg.voltage[0])
        assert rows[int(round(end.t_s / DT)) - 1, 3] == pytest.approx(w_ss, rel=0.01), label
    # not told (the old way): the first level ends at its minimum hold, the rotor at rest
    blind = Session(plan, safety, tau_m_s=tau)
    rows = _run(blind, spec.model, noise=(0.01, 0.05), open_for=late)
    assert blind.held_samples["staircase_01"] < late
    end = next(m for m in blind.markers if m.event is MarkerEvent.END)
    assert abs(rows[int(round(end.t_s / DT)) - 1, 3]) < 1.0


def test_a_stale_staircase_level_does_not_pass_for_the_next_one():
    """The previous level still applied (its successor's command late) is not the new
    level's steady state; a reading near the level (a board's own, a sagging supply) is."""
    from pmdc_ident.node_logic.session.machine import _applies

    assert _applies(None, 12.0, 0.0)  # not known: as before
    assert not _applies(math.nan, 12.0, 0.0)  # armature open
    assert not _applies(0.0, 12.0, 0.0)  # the session's 0 V start
    assert not _applies(12.0, 24.0, 12.0)  # the level before
    assert _applies(21.6, 24.0, 12.0)  # 10 % supply sag
    assert _applies(12.0, 12.0, math.nan) and _applies(3.0, 3.0, 3.0)


def test_staircase_that_never_settles_ends_at_the_timeout_and_says_so():
    plan = TestPlan(
        (
            # a sample of the plan type, fed with a ramping speed below
            *plan_for_motor(
                load_motor("seed001_110v"),
                DT,
                SequenceConfig(staircase_levels=2, steps=False, sweep=False, coast=False),
            ).segments[:1],
        ),
        DT,
    )
    n = plan.segments[0].voltage.size
    safety = SafetyConfig(current_max_a=100, speed_max_rad_s=1e6, stall_current_a=99)
    s = Session(plan, safety, tau_m_s=0.05, steady=SteadyStateConfig(timeout_factor=3.0))
    s.start()
    k = 0
    while s.active:
        s.on_sample(k * DT, 1.0, 10.0 + 50.0 * k * DT)  # speed keeps rising
        k += 1
    assert s.settled == {"staircase_01": False}
    assert s.held_samples["staircase_01"] == math.ceil(3.0 * n)


@pytest.mark.parametrize(
    ("current", "speed", "reason"),
    [
        (12.0, 50.0, AbortReason.OVER_CURRENT),
        (1.0, 400.0, AbortReason.OVER_SPEED),
        (6.0, 0.2, AbortReason.STALL),
        (math.nan, 1.0, AbortReason.DRIVER_FAULT),
    ],
)
@pytest.mark.parametrize("mode", [SafeMode.ZERO, SafeMode.OPEN])
def test_each_safety_violation_aborts_with_its_reason_and_the_safe_command(
    current, speed, reason, mode
):
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, DT, SHORT)
    safety = SafetyConfig(
        current_max_a=10.0,
        speed_max_rad_s=300.0,
        stall_current_a=5.0,
        stall_speed_rad_s=1.0,
        stall_time_s=0.1,
    )
    s = Session(plan, safety, tau_m_s=0.05, safe_mode=mode)
    s.start()
    for k in range(50):
        step = s.on_sample(k * DT, 1.0, 20.0)
        assert step.abort_reason is None
    k = 50
    step = s.on_sample(k * DT, current, speed)
    while step.abort_reason is None and k < 500:  # a stall needs stall_time_s to pass
        k += 1
        step = s.on_sample(k * DT, current, speed)
    assert step.abort_reason is reason
    assert s.state is SessionState.ABORTED
    if mode is SafeMode.ZERO:
        assert step.command.voltage_v == 0.0
    else:
        assert step.command.open_armature
    if reason is AbortReason.STALL:
        assert (k - 50) * DT == pytest.approx(0.1, abs=1.5 * DT)
    else:
        assert k == 50
    events = [m.event for m in step.markers]
    assert events == [MarkerEvent.END, MarkerEvent.ABORT, MarkerEvent.SESSION_END]
    # a session once aborted stays safe whatever arrives
    assert s.on_sample((k + 1) * DT, 1.0, 20.0).command is None
    assert s.abort(AbortReason.INTERRUPTED).command == step.command


def test_lost_driver_data_aborts_after_the_timeout_in_wall_time():
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, DT, SHORT)
    safety = replace(SafetyConfig.for_limits(spec.limits, 0.05), data_timeout_s=0.25)
    s = Session(plan, safety, tau_m_s=0.05)
    s.start()
    for k in range(10):
        s.on_sample(k * DT, 0.0, 0.0, wall_s=100.0 + k * DT)
    assert s.check_link(100.2) is None
    step = s.check_link(100.3)
    assert step is not None and step.abort_reason is AbortReason.LOST_DRIVER_DATA
    assert step.command.voltage_v == 0.0
    assert s.check_link(200.0) is None  # aborted once; the node keeps sending safe
    assert s.state is SessionState.ABORTED


def test_plan_check_refuses_voltages_above_the_driver_limit_before_anything_moves():
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, DT, SHORT)
    safety = SafetyConfig.for_limits(spec.limits, 0.05)
    assert check_plan(plan, spec.limits, safety, spec) == []
    low = Limits(voltage_max_v=48.0, current_max_a=40.0, speed_max_rad_s=120.0)
    problems = check_plan(plan, low, safety, spec)
    assert len(problems) == 1 and "110 V" in problems[0] and "48 V" in problems[0]
    slow = replace(safety, speed_max_rad_s=30.0)
    problems = check_plan(plan, spec.limits, slow, spec)
    assert any("rad/s" in p for p in problems)  # 110 V -> ~58 rad/s nominal


def test_marker_json_round_trip():
    m = Marker(MarkerEvent.START, "staircase_03", 12.345, "s1", "")
    assert Marker.from_json(m.to_json()) == m


def test_lost_samples_do_not_stretch_segments_on_the_driver_clock():
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, DT, SHORT)
    tau = spec.model.params.mechanical_time_constant_s
    s = Session(plan, SafetyConfig.for_limits(spec.limits, tau), tau_m_s=tau)
    _run(s, spec.model, drop=0.2)
    assert s.state is SessionState.DONE
    assert s.skipped_samples > 0.1 * plan.n_samples
    starts = {m.label: m.t_s for m in s.markers if m.event is MarkerEvent.START}
    ends = {m.label: m.t_s for m in s.markers if m.event is MarkerEvent.END}
    for seg in plan.segments:
        if not seg.label.startswith("staircase"):
            span = (ends[seg.label] - starts[seg.label]) / DT
            assert span == pytest.approx(seg.voltage.size, abs=1e-6), seg.label


def test_progress_names_the_running_test_and_grows_to_one():
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, DT, SHORT)
    tau = spec.model.params.mechanical_time_constant_s
    s = Session(plan, SafetyConfig.for_limits(spec.limits, tau), tau_m_s=tau)
    assert s.progress().state is SessionState.IDLE
    plant = Plant(spec.model, DT, substeps=4)
    s.start()
    seen: list[tuple[str, float]] = []
    v = 0.0
    while s.active:
        step = s.on_sample(plant.time_s, plant.current_a, plant.speed_rad_s)
        v = step.command.voltage_v if step.command else v
        plant.step(v)
        p = s.progress()
        if p.state is SessionState.RUNNING:
            seen.append((p.test, p.total_fraction))
            assert p.test == plan.segments[p.segment_index].label
            assert 0.0 <= p.segment_fraction <= 1.0
    fractions = [f for _, f in seen]
    assert fractions == sorted(fractions)  # never goes back
    assert [t for t, _ in seen][0] == "staircase_01"
    assert {t for t, _ in seen} == {seg.label for seg in plan.segments}
    final = s.progress()
    assert final.state is SessionState.DONE and final.total_fraction == 1.0
    assert '"state":"done"' in final.to_json()
