"""The motor model core against closed forms, the seed-001 paper and its own physics.

Tolerances follow the physics: times to ``atol = dt``, steady states to ``rtol = 1e-6``
after more than 15 time constants, exact-discretisation checks to near round-off.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from pmdc_ident.core.effects import (
    EFFECT_NAMES,
    BrushDrop,
    Cogging,
    CoulombFriction,
    CurrentOffset,
    DeadZone,
    Delay,
    InductanceSaturation,
    LoadTorque,
    QuadraticDrag,
    ResistanceDrift,
    StribeckFriction,
    TorqueDependentFriction,
    effect_from_mapping,
    effects_from_mapping,
)
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.model import (
    Model,
    Plant,
    SimResult,
    _zoh2,
    continuous_state_space,
    discretize_zoh,
    simulate,
    simulate_linear,
)
from pmdc_ident.core.motors import BUILTIN_MOTORS, load_motor
from pmdc_ident.core.params import MotorParams

DT_S = 1e-3
SEED000 = load_motor("seed000_ebike")
SEED001 = load_motor("seed001_110v")
P0 = SEED000.model.params  # the e-bike motor, L/R = 0.22 ms (stiff at 1 kHz)
P1 = SEED001.model.params  # the 110 V motor, complex poles


def _step(n: int, volts: float, rest: int = 0) -> np.ndarray:
    v = np.full(n, volts)
    v[:rest] = 0.0
    return v


# ---------------------------------------------------------------------------
# Closed forms of the linear model
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("params", "volts", "seconds"),
    [(P0, 12.0, 6.0), (P0, -20.0, 6.0), (P1, 80.0, 3.0)],
    ids=["seed000_12V", "seed000_-20V", "seed001_80V"],
)
def test_long_step_ends_at_the_closed_form_steady_state(params, volts, seconds):
    i_ss, w_ss = params.steady_state(volts)
    v = np.full(int(seconds / DT_S), volts)
    for res in (simulate_linear(params, v, DT_S), simulate(Model(params), v, DT_S)):
        assert res.current[-1] == pytest.approx(i_ss, rel=1e-6)
        assert res.speed[-1] == pytest.approx(w_ss, rel=1e-6)


def test_steady_state_with_load_torque_balances_both_equations():
    i, w = P0.steady_state(12.0, load_torque_nm=0.05)
    assert 12.0 - P0.R * i - P0.Ke * w == pytest.approx(0.0, abs=1e-12)
    assert P0.Kt * i - P0.B * w - 0.05 == pytest.approx(0.0, abs=1e-12)


def test_speed_rises_to_63_percent_after_one_mechanical_time_constant():
    p = P0.replace(L=1e-9)  # L/R ~ 1 ns: speed is first order with tau_m
    tau = p.mechanical_time_constant_s
    res = simulate_linear(p, np.full(int(3 * tau / DT_S), 10.0), DT_S)
    _, w_ss = p.steady_state(10.0)
    target = (1.0 - math.exp(-1.0)) * w_ss
    k = int(np.argmax(res.speed >= target))
    # linear interpolation between the samples around the crossing
    frac = (target - res.speed[k - 1]) / (res.speed[k] - res.speed[k - 1])
    t_rise = (k - 1 + frac) * DT_S
    assert t_rise == pytest.approx(tau, abs=DT_S)
    assert tau == pytest.approx(0.2987, rel=1e-3)  # seed 000: J R / (R B + Ke Kt)


def test_zoh_simulation_equals_continuous_integration_at_the_samples():
    rng = np.random.default_rng(7)
    dt = 2e-3
    v = np.repeat(rng.uniform(-100.0, 100.0, 12), 10)  # piecewise constant, 120 samples
    res = simulate_linear(P1, v, dt)
    a, b = continuous_state_space(P1)

    def rhs(_t: float, x: np.ndarray, volts: float) -> np.ndarray:
        return np.array([*(a @ x[:2] + b[:, 0] * volts), x[1]])

    x = np.zeros(3)
    ref = [x]
    for vk in v[:-1]:
        sol = solve_ivp(rhs, (0.0, dt), x, args=(vk,), method="DOP853", rtol=1e-12, atol=1e-12)
        x = sol.y[:, -1]
        ref.append(x)
    ref_arr = np.array(ref)
    np.testing.assert_allclose(res.current, ref_arr[:, 0], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(res.speed, ref_arr[:, 1], rtol=1e-8, atol=1e-9)
    np.testing.assert_allclose(res.position, ref_arr[:, 2], rtol=1e-8, atol=1e-9)


def test_discretize_zoh_phi_is_the_matrix_exponential_with_integrating_angle():
    phi, gam = discretize_zoh(P1, 1e-3)
    a, _ = continuous_state_space(P1)
    from scipy.linalg import expm

    np.testing.assert_allclose(phi[:2, :2], expm(a * 1e-3), rtol=1e-12)
    np.testing.assert_allclose(phi[2], [phi[2, 0], phi[2, 1], 1.0])
    assert gam.shape == (3, 2)


@pytest.mark.parametrize("params", [P0, P1], ids=["real_poles", "complex_poles"])
def test_closed_form_2x2_exponential_matches_expm(params):
    from scipy.linalg import expm

    a, _ = continuous_state_space(params)
    h = 1.25e-4
    e11, e12, e21, e22, g11, g12, g21, g22 = _zoh2(a[0, 0], a[0, 1], a[1, 0], a[1, 1], h)
    e_ref = expm(a * h)
    g_ref = np.linalg.solve(a, e_ref - np.eye(2))
    np.testing.assert_allclose([[e11, e12], [e21, e22]], e_ref, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose([[g11, g12], [g21, g22]], g_ref, rtol=1e-9, atol=1e-16)


# ---------------------------------------------------------------------------
# Seed 001: eq. 4 and 5 from its Table 4 first trial
# ---------------------------------------------------------------------------
def test_seed001_transfer_functions_reproduce_eq4_and_eq5():
    tfs = P1.transfer_functions()
    num_i, den_i = tfs["current_per_voltage"]
    num_w, den_w = tfs["speed_per_voltage"]
    printed_den = [0.1042, 3.123, 60.83]
    for got, want in zip(den_i, printed_den, strict=True):
        assert got == pytest.approx(want, rel=1e-3)
    assert den_w == den_i
    for got, want in zip(num_i, [1.0, 0.7176], strict=True):
        assert got == pytest.approx(want, rel=1e-3)
    assert num_w[0] == pytest.approx(31.96, rel=1e-3)


def test_seed001_simulated_dc_gains_match_its_transfer_functions():
    tfs = P1.transfer_functions()
    num_i, den_i = tfs["current_per_voltage"]
    num_w, den_w = tfs["speed_per_voltage"]
    gain_i = num_i[-1] / den_i[-1]  # TF at s = 0
    gain_w = num_w[-1] / den_w[-1]
    res = simulate_linear(P1, np.full(3000, 50.0), DT_S)
    assert res.current[-1] / 50.0 == pytest.approx(gain_i, rel=1e-6)
    assert res.speed[-1] / 50.0 == pytest.approx(gain_w, rel=1e-6)
    assert gain_w == pytest.approx(31.96 / 60.83, rel=1e-3)


# ---------------------------------------------------------------------------
# Open armature: coast-down
# ---------------------------------------------------------------------------
def test_open_armature_coast_with_viscous_friction_decays_exponentially():
    w0 = 100.0
    v = np.full(3000, np.nan)
    expected = w0 * np.exp(-P0.B / P0.J * np.arange(v.size) * DT_S)
    for res in (
        simulate_linear(P0, v, DT_S, x0=[0.0, w0, 0.0]),
        simulate(Model(P0), v, DT_S, x0=[0.0, w0, 0.0]),
    ):
        np.testing.assert_allclose(res.speed, expected, rtol=1e-9)
        assert np.all(res.current[1:] == 0.0)  # open winding: no current


def test_open_armature_coast_with_coulomb_stops_at_closed_form_time():
    tc, w0 = 0.0256, 100.0
    t_stop = P0.J / P0.B * math.log(1.0 + P0.B * w0 / tc)  # 3.4186 s
    res = simulate(SEED000.model, np.full(int((t_stop + 1.0) / DT_S), np.nan), DT_S, x0=[0, w0, 0])
    k = int(np.argmax(res.speed <= 0.0))
    assert k * DT_S == pytest.approx(t_stop, abs=DT_S)
    assert np.all(res.speed[k:] == 0.0)  # stays stopped, no chatter
    pos_stop = res.position[k]
    assert np.all(res.position[k:] == pos_stop)


# ---------------------------------------------------------------------------
# Stiction
# ---------------------------------------------------------------------------
def test_stiction_holds_the_rotor_below_breakaway_and_releases_above():
    tc = 0.0256
    v_break = tc * P0.R / P0.Kt  # 0.522 V: stall torque Kt V / R equals Tc
    held = simulate(SEED000.model, np.full(1000, 0.9 * v_break), DT_S)
    assert np.all(held.speed == 0.0)
    assert np.all(held.position == 0.0)
    assert held.current[-1] == pytest.approx(0.9 * v_break / P0.R, rel=1e-9)
    moving = simulate(SEED000.model, np.full(1000, 1.1 * v_break), DT_S)
    assert moving.speed[-1] > 0.1
    i_ss, w_ss = P0.steady_state(1.1 * v_break, load_torque_nm=tc)
    assert moving.speed[-1] == pytest.approx(w_ss, rel=0.05)


def test_rotor_stopped_by_friction_under_small_voltage_stays_stopped():
    v = np.concatenate([np.full(1500, 12.0), np.full(6000, 0.3)])  # 0.3 V < breakaway
    res = simulate(SEED000.model, v, DT_S)
    tail = res.speed[-1000:]
    assert np.all(tail == 0.0)


# ---------------------------------------------------------------------------
# Every effect changes the response the way its physics says
# ---------------------------------------------------------------------------
N_EFF = 3000
V_EFF = 12.0


@functools.cache
def _base() -> SimResult:
    """The effect-free step response the effects are compared with: computed on first
    use, not at import (collection would compile the model's kernels in every pytest
    process before the suite's one compile has filled the cache)."""
    return simulate(Model(P0), _step(N_EFF, V_EFF, rest=100), DT_S)


def _with(*effects) -> object:
    return simulate(Model(P0, effects), _step(N_EFF, V_EFF, rest=100), DT_S)


def test_effect_coulomb_friction_lowers_top_speed_to_the_closed_form():
    res = _with(CoulombFriction(0.02))
    _, w_ss = P0.steady_state(V_EFF, load_torque_nm=0.02)
    assert res.speed[-1] == pytest.approx(w_ss, rel=1e-4)
    assert res.speed[-1] < _base().speed[-1] - 5.0


def test_effect_stribeck_raises_breakaway_and_slows_the_start_but_not_top_speed():
    ts = 0.03
    v_hold = 0.9 * ts * P0.R / P0.Kt  # below Ts R / Kt: held at rest by the breakaway torque
    held = simulate(Model(P0, (StribeckFriction(ts, 2.0),)), np.full(500, v_hold), DT_S)
    assert np.all(held.speed == 0.0)
    free = simulate(Model(P0), np.full(500, v_hold), DT_S)
    assert free.speed[-1] > 1.0
    res = _with(StribeckFriction(ts, 2.0))
    k = 100 + 30  # 30 ms after the step: the extra torque acted while w < ~2 rad/s
    assert _base().speed[k] - res.speed[k] > 0.05
    assert res.speed[-1] == pytest.approx(_base().speed[-1], rel=1e-5)


def test_effect_quadratic_drag_lowers_top_speed_to_the_quadratic_root():
    cq = 1e-6
    res = _with(QuadraticDrag(cq))
    # Kt (V - Ke w) / R = B w + cq w^2
    a, b, c = cq, P0.B + P0.Kt * P0.Ke / P0.R, -P0.Kt * V_EFF / P0.R
    w_ss = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)
    assert res.speed[-1] == pytest.approx(w_ss, rel=1e-4)
    assert res.speed[-1] < _base().speed[-1] - 5.0


def test_effect_load_torque_matches_steady_state_with_load():
    res = _with(LoadTorque(0.05))
    i_ss, w_ss = P0.steady_state(V_EFF, load_torque_nm=0.05)
    assert res.speed[-1] == pytest.approx(w_ss, rel=1e-4)
    # the speed transient left after ~10 tau_m (e^-10 of 9 A at the start) is < 1 mA
    assert res.current[-1] == pytest.approx(i_ss, abs=1e-3)


def test_effect_brush_drop_lowers_steady_speed_by_drop_over_ke():
    vb = 1.0
    res = _with(BrushDrop(vb))
    _, w_ss = P0.steady_state(V_EFF - vb)
    assert res.speed[-1] == pytest.approx(w_ss, rel=1e-4)
    # the speed loss is ~ Vb / Ke (B is small against Ke Kt / R)
    assert _base().speed[-1] - res.speed[-1] == pytest.approx(vb / P0.Ke, rel=0.05)


def test_smooth_brush_drop_settles_where_its_tanh_law_balances_the_voltage():
    # a contact film: the drop is vb tanh(i / i_knee), so at a no-load current near the
    # knee only part of vb is lost (the hard sign would take all of it)
    from scipy.optimize import brentq

    vb = 1.0
    knee, _ = P0.steady_state(V_EFF - vb)  # the hard sign's no-load current

    def settled(*effects: BrushDrop) -> float:  # the knee's slope slows the settling
        return float(simulate(Model(P0, effects), np.full(12_000, V_EFF), DT_S).speed[-1])

    # steady state: V = i (R + Ke Kt / B) + vb tanh(i / knee), w = Kt i / B
    i_ss = brentq(
        lambda i: i * (P0.R + P0.Ke * P0.Kt / P0.B) + vb * math.tanh(i / knee) - V_EFF,
        0.0,
        V_EFF / P0.R,
    )
    assert settled(BrushDrop(vb, knee)) == pytest.approx(P0.Kt * i_ss / P0.B, rel=1e-4)
    assert settled(BrushDrop(vb, knee)) > settled(BrushDrop(vb)) + 0.1 * vb / P0.Ke
    # a knee far below the current is the hard sign
    assert settled(BrushDrop(vb, 1e-4 * knee)) == pytest.approx(settled(BrushDrop(vb)), rel=1e-4)


def test_a_lag_holds_each_samples_mean_of_the_first_order_response():
    from pmdc_ident.core.model import apply_lag

    tau, dt = 4e-3, 1e-3
    v = np.r_[np.full(20, 2.0), np.nan, np.full(3, 2.0)]
    got = apply_lag(v, tau, dt)
    k = np.arange(20)
    # the mean of 2 (1 - exp(-t/tau)) over [k dt, (k+1) dt)
    mean = 2.0 * (1.0 - tau / dt * (np.exp(-k * dt / tau) - np.exp(-(k + 1) * dt / tau)))
    np.testing.assert_allclose(got[:20], mean, rtol=1e-12)
    assert math.isnan(got[20]) and got[21] == pytest.approx(mean[0])  # open: restarts
    assert apply_lag(v, 0.0, dt) is v


def test_effect_dead_zone_gives_no_motion_below_threshold_and_shifts_above():
    dz = DeadZone(1.0)
    below = simulate(Model(P0, (dz,)), np.full(500, 0.95), DT_S)
    assert np.all(below.speed == 0.0) and np.all(below.current == 0.0)
    assert np.all(below.applied_voltage == 0.0)
    res = _with(dz)
    _, w_ss = P0.steady_state(V_EFF - 1.0)
    assert res.speed[-1] == pytest.approx(w_ss, rel=1e-4)
    neg = simulate(Model(P0, (dz,)), np.full(500, -3.0), DT_S)
    assert neg.applied_voltage[0] == pytest.approx(-2.0)


def test_effect_cogging_makes_speed_ripple_at_periods_per_rev_per_turn():
    n_cog = 6.0
    res = _with(Cogging(0.01, n_cog))
    tail = slice(N_EFF - 1000, N_EFF)  # last second, near top speed

    def ripple_spectrum(speed: np.ndarray) -> np.ndarray:
        w, t = speed[tail], _base().t[tail]
        ripple = w - np.polyval(np.polyfit(t, w, 2), t)  # remove the slow approach to top speed
        return np.abs(np.fft.rfft(ripple * np.hanning(ripple.size)))

    spec = ripple_spectrum(res.speed)
    freqs = np.fft.rfftfreq(1000, DT_S)
    fast = freqs > 20.0  # the slow trend leaks into the lowest bins
    k_peak = int(np.argmax(spec * fast))
    f_expected = n_cog * res.speed[tail].mean() / (2.0 * math.pi)  # ~169 Hz
    assert freqs[k_peak] == pytest.approx(f_expected, abs=2.0)  # bin width 1 Hz
    assert spec[k_peak] > 20.0 * np.median(spec[fast])
    assert spec[k_peak] > 100.0 * ripple_spectrum(_base().speed)[k_peak]


def test_effect_resistance_drift_lowers_stall_current_as_the_closed_form():
    # rotor held by a large friction: R(t) i = V with dq/dt = i^2 gives
    # i(t) = V/R0 (1 + 3 k V^2 t / R0^2)^(-1/3)
    k, v = 0.01, 5.0
    res = simulate(Model(P0, (CoulombFriction(50.0), ResistanceDrift(k))), np.full(5000, v), DT_S)
    expected = v / P0.R * (1.0 + 3.0 * k * v * v * res.t / P0.R**2) ** (-1.0 / 3.0)
    np.testing.assert_allclose(res.current[5:], expected[5:], rtol=2e-4)
    assert res.current[-1] < 0.8 * v / P0.R


def test_effect_delay_shifts_the_response_by_the_delay():
    whole = _with(Delay(0.005))
    np.testing.assert_allclose(whole.speed[5:], _base().speed[:-5], rtol=1e-12, atol=1e-12)
    frac = _with(Delay(0.0025))
    half = 0.5 * _base().speed[-1]

    def crossing(speed: np.ndarray) -> float:
        k = int(np.argmax(speed >= half))
        return (k - 1 + (half - speed[k - 1]) / (speed[k] - speed[k - 1])) * DT_S

    assert crossing(frac.speed) - crossing(_base().speed) == pytest.approx(0.0025, abs=DT_S)


def test_effect_current_offset_shifts_current_by_exactly_the_offset():
    res = _with(CurrentOffset(0.1))
    np.testing.assert_allclose(res.current - _base().current, 0.1, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(res.speed, _base().speed)


def test_effect_inductance_saturation_speeds_the_current_rise_at_high_current():
    # seed 001: L/R = 34 ms, so the rise is resolved; rotor held to keep current high
    hold = CoulombFriction(1e3)
    v = np.full(100, 100.0)  # stall current 33 A
    plain = simulate(Model(P1, (hold,)), v, DT_S)
    sat = simulate(Model(P1, (hold, InductanceSaturation(5.0))), v, DT_S)
    half = 0.5 * 100.0 / P1.R
    t_plain = int(np.argmax(plain.current >= half))
    t_sat = int(np.argmax(sat.current >= half))
    assert t_plain == pytest.approx(P1.L / P1.R * math.log(2) / DT_S, abs=1)
    assert t_sat < 0.5 * t_plain
    # both end at the same stall current V/R
    assert sat.current[-1] == pytest.approx(100.0 / P1.R, rel=1e-3)


def test_effect_torque_dependent_friction_takes_its_share_driving_and_adds_it_braking():
    mu = 0.3
    # the torque is smaller while driving: the rotor settles later (tau_m / (1 - mu))
    v = np.concatenate([np.full(8000, V_EFF), np.zeros(300)])
    plain = simulate(Model(P0), v, DT_S).speed
    res = simulate(Model(P0, (TorqueDependentFriction(mu),)), v, DT_S).speed
    # V = R i + Ke w and Kt (1 - mu) i = B w: the share mu of the torque is lost
    w_ss = V_EFF / (P0.R * P0.B / (P0.Kt * (1.0 - mu)) + P0.Ke)
    assert res[7999] == pytest.approx(w_ss, rel=1e-6)
    assert res[7999] < plain[7999] - 1.0  # (a no-load current: a small share of it)
    # shorted at 0 V the winding brakes the rotor: the friction then adds to the torque
    lost = (plain[8000] - plain[8200]) / plain[8000], (res[8000] - res[8200]) / res[8000]
    assert lost[1] > lost[0] + 0.05  # a larger share of the speed is gone 0.2 s later


def test_every_vocabulary_effect_has_a_direction_test():
    tested = {
        "coulomb_friction",
        "stribeck_friction",
        "quadratic_drag",
        "load_torque",
        "brush_drop",
        "dead_zone",
        "cogging",
        "resistance_drift",
        "delay",
        "current_offset",
        "inductance_saturation",
        "torque_dependent_friction",
    }
    assert tested == set(EFFECT_NAMES)


# ---------------------------------------------------------------------------
# Plant (streaming) = simulate
# ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    "effects",
    [
        (
            CoulombFriction(0.02),
            DeadZone(0.5),
            Delay(0.0025),
            CurrentOffset(0.05),
            Cogging(0.005, 4.0),
            QuadraticDrag(1e-6),
            ResistanceDrift(1e-3),
        ),
        (BrushDrop(0.8, 0.3), Delay(0.0025)),  # the knee's slope alone varies R
        (Delay(0.001, 0.004), CurrentOffset(0.05)),  # a lag's state carried across steps
    ],
)
def test_plant_stepped_sample_by_sample_equals_simulate(effects):
    rng = np.random.default_rng(3)
    v = np.repeat(rng.uniform(-20.0, 20.0, 40), 25)
    v[400:600] = np.nan  # an open-armature stretch
    model = Model(P0, effects)
    ref = simulate(model, v, DT_S)
    plant = Plant(model, DT_S)
    got = np.empty((v.size, 3))
    for k, vk in enumerate(v):
        got[k] = plant.current_a, plant.speed_rad_s, plant.position_rad
        plant.step(None if math.isnan(vk) else vk)
    assert plant.time_s == pytest.approx(v.size * DT_S)
    np.testing.assert_allclose(got[:, 0], ref.current, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[:, 1], ref.speed, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[:, 2], ref.position, rtol=0, atol=1e-12)


# ---------------------------------------------------------------------------
# Validation and motor files
# ---------------------------------------------------------------------------
GOOD = {"R": 1.0, "L": 1e-3, "Ke": 0.05, "Kt": 0.05, "J": 1e-4, "B": 1e-5}


@pytest.mark.parametrize(
    ("change", "fragment"),
    [
        ({"R": -1.0}, "R (armature resistance) must be > 0 ohm"),
        ({"J": math.nan}, "J must be finite"),
        ({"B": -1e-6}, "B (viscous friction coefficient) must be >= 0"),
        ({"Ke": "abc"}, "Ke must be a number"),
    ],
)
def test_bad_motor_parameters_raise_parameter_error_with_a_clear_line(change, fragment):
    with pytest.raises(ParameterError, match=None) as info:
        MotorParams(**{**GOOD, **change})
    text = str(info.value)
    assert fragment in text
    assert "\n" not in text


def test_unknown_effect_is_a_parameter_error_naming_the_known_ones():
    with pytest.raises(ParameterError, match="unknown effect 'backlash'; known: coulomb"):
        effect_from_mapping("backlash", {})
    with pytest.raises(ParameterError, match="delay.delay_s .* must lie in"):
        effects_from_mapping({"delay": {"delay_s": -1.0}})
    with pytest.raises(ParameterError, match="each effect may appear once"):
        Model(MotorParams(**GOOD), (Delay(0.001), Delay(0.002)))


def test_model_refuses_effects_that_are_not_effect_objects():
    with pytest.raises(ParameterError, match=r"model effects must be Effect objects .* got .fan."):
        Model(MotorParams(**GOOD), ("fan",))
    with pytest.raises(ParameterError, match="a model needs MotorParams, got dict"):
        Model(GOOD)


def test_bad_time_step_and_infinite_voltage_are_refused():
    with pytest.raises(ParameterError, match="dt_s must be a positive"):
        simulate_linear(P0, [1.0, 2.0], 0.0)
    with pytest.raises(ParameterError, match="inf is refused"):
        simulate(Model(P0), [1.0, math.inf], DT_S)


@pytest.mark.parametrize("name", BUILTIN_MOTORS)
def test_builtin_motors_load_with_their_paper_parameters(name):
    spec = load_motor(name)
    assert spec.name == name
    assert spec.limits.voltage_max_v > 0
    if name == "seed001_110v":
        assert spec.model.params.R == pytest.approx(3.04840)
        assert spec.model.effects == ()
    else:
        assert spec.model.params.L == pytest.approx(298.75e-6)
        assert spec.model.effect_names == ("coulomb_friction",)


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        ("parameters: [1, 2\n", "not valid YAML"),
        ("name: x\n", "needs a 'parameters' mapping"),
        ("parameters: {R: -1, L: 1, Ke: 1, Kt: 1, J: 1, B: 0}\n", "R (armature resistance)"),
        (
            "parameters: {R: 1, L: 1, Ke: 1, Kt: 1, J: 1, B: 0}\neffects: {fan: {}}\n",
            "unknown effect 'fan'",
        ),
        (
            "parameters: {R: 1, L: 1, Ke: 1, Kt: 1, J: 1, B: 0}\nlimits: {voltage_max_v: -5}\n",
            "voltage_max_v must be finite and > 0",
        ),
    ],
    ids=["syntax", "no_parameters", "negative_R", "unknown_effect", "bad_limit"],
)
def test_bad_motor_yaml_is_one_clear_parameter_error(tmp_path, text, fragment):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ParameterError) as info:
        load_motor(path)
    assert fragment in str(info.value)
    assert str(path) in str(info.value)
    assert "\n" not in str(info.value)


def test_missing_motor_file_names_the_builtins():
    with pytest.raises(ParameterError, match="built-in motors: seed000_ebike, seed001_110v"):
        load_motor("/nonexistent/motor.yaml")


def test_a_drive_that_reverses_the_rotor_carries_it_through_zero():
    """A +-6 V pseudo-random drive at 50 Hz reverses a small rotor (mechanical time
    constant ~ one sample) in most samples. With negligible Coulomb friction the speed
    must follow the linear model: clamping it to 0 at each crossing (the drive breaks
    it away at once) lost the rest of the sub-step's motion, 19 rad/s rms here."""
    p = MotorParams(R=8.0, L=2e-3, Ke=0.008, Kt=0.008, J=2e-7, B=1e-8)
    rng = np.random.default_rng(3)
    v = (rng.integers(0, 2, 400) * 2 - 1) * 6.0
    lin = simulate_linear(p, v, 0.02)
    tiny = simulate(Model(p, (CoulombFriction(1e-12),)), v, 0.02)
    assert np.sqrt(np.mean((tiny.speed - lin.speed) ** 2)) < 1e-3 * np.ptp(lin.speed)
    # a real friction torque still stops a rotor the drive cannot move: open coast
    coast = simulate(Model(p, (CoulombFriction(2e-4),)), np.r_[6.0, np.full(60, np.nan)], 0.02)
    assert coast.speed[-1] == 0.0 and coast.final_state[4] == 1.0
