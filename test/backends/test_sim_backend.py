"""SimBackend and SafetyMonitor without ROS: exact grid, clamping, safety, sensors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pmdc_ident.backends.base import Backend, BackendError, Telemetry
from pmdc_ident.backends.sim import SimBackend
from pmdc_ident.core.enums import Fault, SafeMode
from pmdc_ident.core.excitation import apply_sensors
from pmdc_ident.core.model import simulate
from pmdc_ident.core.motors import Limits, SensorSpec, load_motor

SEED000 = load_motor("seed000_ebike")
DT_S = 1e-3
EXACT = SensorSpec()  # no noise, exact angle


class FakeClock:
    def __init__(self, t: float = 100.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t

    def advance(self, seconds: float) -> None:
        self.t += seconds


def _backend(**kw) -> tuple[SimBackend, FakeClock]:
    clock = FakeClock()
    kw.setdefault("sensors", EXACT)
    be = SimBackend(SEED000, DT_S, clock=clock, **kw)
    be.start()
    return be, clock


def test_sim_backend_satisfies_the_backend_protocol():
    be, _ = _backend()
    assert isinstance(be, Backend)


def test_starts_with_armature_open_and_sample_zero_at_time_zero():
    be, _ = _backend()
    out = be.poll()
    assert len(out) == 1
    assert out[0].sample_index == 0 and out[0].time_s == 0.0
    assert out[0].armature_open and be.armature_open


def test_poll_returns_exactly_the_samples_due_whatever_the_timer_jitter():
    be, clock = _backend()
    rng = np.random.default_rng(0)
    got: list[Telemetry] = []
    elapsed = 0.0
    for _ in range(200):
        step = float(rng.uniform(0.0, 4.3e-3))  # jittery host timer
        clock.advance(step)
        elapsed += step
        got += be.poll()
    assert len(got) == math.floor(elapsed / DT_S) + 1
    idx = np.array([s.sample_index for s in got])
    np.testing.assert_array_equal(idx, np.arange(idx.size))
    times = np.array([s.time_s for s in got])
    np.testing.assert_allclose(times, idx * DT_S, rtol=0, atol=1e-12)


def test_command_sequence_reproduces_simulate_on_the_grid():
    be, clock = _backend()
    be.poll()  # sample 0 (open)
    be.command_voltage(12.0)
    got: list[Telemetry] = []
    for _ in range(150):
        clock.advance(3.7e-3)  # polls at an unrelated period
        got += be.poll()
    n = len(got)
    v = np.concatenate([[np.nan], np.full(n, 12.0)])
    ref = simulate(SEED000.model, v, DT_S)
    np.testing.assert_allclose([s.current_a for s in got], ref.current[1:], atol=1e-12)
    np.testing.assert_allclose([s.speed_rad_s for s in got], ref.speed[1:], atol=1e-12)
    np.testing.assert_allclose([s.position_rad for s in got], ref.position[1:], atol=1e-12)
    assert all(s.voltage_cmd_v == 12.0 for s in got)


def test_command_takes_effect_at_the_next_grid_instant_after_it_arrives():
    be, clock = _backend()
    clock.advance(2.5e-3)  # samples 0, 1, 2 exist
    be.command_voltage(5.0)  # arrives between samples 2 and 3
    clock.advance(2.0e-3)
    out = be.poll()
    assert [s.sample_index for s in out] == [0, 1, 2, 3, 4]
    assert [s.armature_open for s in out] == [True, True, True, False, False]


def test_command_beyond_the_limit_is_clamped_and_flagged():
    be, clock = _backend(limits=Limits(voltage_max_v=10.0))
    assert be.command_voltage(30.0) == 10.0
    assert be.command_voltage(-30.0) == -10.0
    clock.advance(1e-3)
    out = be.poll()
    assert out[-1].voltage_cmd_v == -10.0
    assert out[-1].faults & Fault.CLAMPED
    assert be.command_voltage(3.0) == 3.0
    clock.advance(1e-3)
    assert be.poll()[-1].faults == Fault.NONE


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, "12"])
def test_non_finite_command_is_refused_and_the_motor_state_kept(bad):
    be, clock = _backend()
    be.command_voltage(4.0)
    if isinstance(bad, str):
        assert be.command_voltage(bad) == 12.0  # a numeric string is a number
        return
    with pytest.raises(BackendError, match="refused"):
        be.command_voltage(bad)
    assert be.command_v == 4.0  # the caller decides to make it safe
    clock.advance(1e-3)
    assert be.poll()[-1].faults & Fault.BAD_COMMAND


def test_command_before_start_is_refused():
    be = SimBackend(SEED000, DT_S, clock=FakeClock())
    with pytest.raises(BackendError, match="not started"):
        be.command_voltage(1.0)
    assert be.poll() == []


@pytest.mark.parametrize(("mode", "expected"), [(SafeMode.OPEN, math.nan), (SafeMode.ZERO, 0.0)])
def test_make_safe_follows_the_safe_mode_and_is_idempotent(mode, expected):
    be, clock = _backend(safe_mode=mode)
    be.command_voltage(12.0)
    be.make_safe()
    be.make_safe()
    clock.advance(1e-3)
    v = be.poll()[-1].voltage_cmd_v
    assert (math.isnan(v) and math.isnan(expected)) or v == expected
    be.close()
    be.close()
    assert not be.started


def test_open_armature_lets_the_rotor_coast_with_zero_current():
    be, clock = _backend()
    be.command_voltage(12.0)
    clock.advance(1.0)
    be.poll()
    w_before = be.plant.speed_rad_s
    be.open_armature()
    clock.advance(0.2)
    out = be.poll()
    assert all(s.armature_open for s in out)
    assert out[-1].current_a == 0.0
    # Coulomb 0.0256 N*m dominates: deceleration ~ (Tc + B w) / J ~ 38 rad/s^2
    assert 0.0 < w_before - out[-1].speed_rad_s < 0.2 * 45.0


def test_zero_volts_brakes_harder_than_an_open_armature():
    speeds = {}
    for name, action in (("open", "open_armature"), ("zero", "zero")):
        be, clock = _backend()
        be.command_voltage(12.0)
        clock.advance(1.0)
        be.poll()
        if action == "zero":
            be.command_voltage(0.0)
        else:
            be.open_armature()
        clock.advance(0.1)
        speeds[name] = be.poll()[-1].speed_rad_s
    # shorted winding: speed decays with tau_m = 0.30 s (x0.72 in 0.1 s); open: only friction
    assert speeds["zero"] < 0.8 * speeds["open"]
    assert speeds["open"] > 155.0


def test_over_current_makes_the_motor_safe_from_that_very_sample_whatever_the_polling():
    be, clock = _backend(limits=Limits(voltage_max_v=24.0, current_max_a=30.0))
    be.command_voltage(24.0)
    clock.advance(1.5)  # ~300 rad/s: back-EMF ~20 V
    be.poll()
    be.command_voltage(-24.0)  # (-24 - 20) V / 1.375 ohm ~ -32 A
    clock.advance(0.05)  # one late poll: 50 samples in one batch
    out = be.poll()
    cur = np.array([s.current_a for s in out])
    k = int(np.argmax(np.abs(cur) > 30.0))
    assert abs(cur[k]) > 30.0 and k > 0
    assert all(s.voltage_cmd_v == -24.0 for s in out[:k])
    assert all(s.armature_open and s.faults & Fault.OVER_CURRENT for s in out[k:])
    assert be.command_voltage(1.0) == 1.0  # a new command clears the backend's flag
    clock.advance(1e-3)
    assert not be.poll()[-1].faults & Fault.OVER_CURRENT


def test_host_stall_returns_a_bounded_backlog_flagged_and_keeps_the_grid():
    be, clock = _backend(max_catch_up_s=0.5)
    be.command_voltage(12.0)
    be.poll()
    clock.advance(2.0)  # the host slept 2 s
    out = be.poll()
    assert len(out) <= 500
    assert out[0].faults & Fault.LINK
    assert not any(s.faults & Fault.LINK for s in out[1:])
    assert be.skipped_samples == pytest.approx(1501, abs=1)
    assert be.stalls == 1
    # the plant kept turning through the gap: stamps stay wall-aligned
    assert out[-1].time_s == pytest.approx(2.0, abs=DT_S)
    ref = simulate(SEED000.model, np.concatenate([[np.nan], np.full(2000, 12.0)]), DT_S)
    assert out[-1].speed_rad_s == pytest.approx(ref.speed[out[-1].sample_index], abs=1e-9)
    clock.advance(0.01)
    nxt = be.poll()
    assert nxt[0].sample_index == out[-1].sample_index + 1


def test_very_long_stall_freezes_the_motor_instead_of_simulating_hours():
    be, clock = _backend(max_catch_up_s=0.5, max_silent_s=1.0)
    be.command_voltage(12.0)
    clock.advance(3600.0)
    out = be.poll()
    assert len(out) <= 500
    assert be.plant.samples <= 1500 + 2


def test_sensor_noise_is_seeded_and_has_the_configured_spread():
    spec_sensors = SensorSpec(current_noise_a=0.01, speed_noise_rad_s=0.05)
    runs = []
    for _ in range(2):
        be, clock = _backend(sensors=spec_sensors, seed=5)
        clock.advance(2.0)
        runs.append(be.poll())
    a = np.array([s.current_a for s in runs[0]])
    b = np.array([s.current_a for s in runs[1]])
    np.testing.assert_array_equal(a, b)
    assert np.std(a) == pytest.approx(0.01, rel=0.1)  # armature open: true current 0
    w = np.array([s.speed_rad_s for s in runs[0]])
    assert np.std(w) == pytest.approx(0.05, rel=0.1)


def test_encoder_reading_is_quantised_to_whole_counts():
    be, clock = _backend(sensors=SensorSpec(encoder_counts_per_rev=4096))
    be.command_voltage(5.0)
    clock.advance(0.5)
    out = be.poll()
    step = 2 * math.pi / 4096
    counts = np.array([s.position_rad for s in out]) / step
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    true = be.plant.position_rad
    _, _, th = apply_sensors(np.zeros(1), np.zeros(1), np.array([true]), be._sensors, None)
    assert 0.0 <= true - th[0] < step


def test_bad_sample_period_is_refused():
    with pytest.raises(BackendError, match="dt_s must be a positive"):
        SimBackend(SEED000, 0.0)
