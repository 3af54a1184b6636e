"""A foreign-shapes corpus: motor records the project's simulator did not make.

Issue 22: the tool was certain where it should doubt on records whose shape it had
never met. Each record here is built by equations written in this file and
integrated by scipy's ``solve_ivp`` (LSODA, adaptive Adams/BDF steps, over each
hold of the command: nothing of the package's exact
zero-order-hold discretisation), or by MuJoCo's own ``<dcmotor>`` actuator
(:mod:`pmdc_ident.benchmark.mujoco_plant`). Sensors are modelled here too: a
current sensor behind a continuous RC filter (a state of the ODE, not a digital
filter), a tachogenerator with its own lag, speed quantised to encoder counts per
sample, a winding that heats.

:func:`corpus` returns every record with its truth and the outcome expected of it;
``test/core/test_foreign_corpus.py`` asserts those outcomes and
``benchmarks/bench_assumptions.py`` scores them before/after.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

METHOD = "LSODA"  # scipy's Adams/BDF switcher, adaptive steps

__all__ = [
    "ForeignRecord",
    "Plant",
    "Sensors",
    "confident_wrong",
    "corpus",
    "flagged",
    "integrate",
    "record_by_name",
]


@dataclass(frozen=True)
class Plant:
    """``L di/dt = Va - R(T) i - Ke w``; ``J dw/dt = Kt i - B w - Tc tanh(w / w_c)``.

    ``heat_per_a2s`` K per A^2*s and ``cool_s``: winding temperature rise T with
    ``dT/dt = heat_per_a2s i^2 - T / cool_s``, ``R(T) = R (1 + 0.0039 T)``.
    ``drive_tau_s``: the drive applies the command through a first-order lag (a
    drive that ramps its output), 0 = at once.
    """

    R: float
    L: float
    Ke: float
    Kt: float
    J: float
    B: float
    Tc: float = 0.0
    heat_per_a2s: float = 0.0
    cool_s: float = math.inf
    drive_tau_s: float = 0.0

    def truth(self) -> dict[str, float]:
        return {
            "R": self.R,
            "L": self.L,
            "Ke": self.Ke,
            "Kt": self.Kt,
            "J": self.J,
            "B": self.B,
            "coulomb_friction.torque_nm": self.Tc,
        }


@dataclass(frozen=True)
class Sensors:
    """Measurement chain: noise (sd), a current filter and a speed lag (time constants,
    continuous), speed quantised to whole counts of an encoder per sample."""

    current_sd: float = 0.002
    speed_sd: float = 0.05
    current_tau_s: float = 0.0
    speed_tau_s: float = 0.0
    speed_counts_per_rev: int = 0  # speed = counts in the last sample / dt
    position: bool = False  # write a position column too


@dataclass
class ForeignRecord:
    """One corpus record: its columns, the truth and what the tool must say about it."""

    name: str
    describe: str
    columns: dict[str, np.ndarray]
    labels: list[str] | None
    truth: dict[str, float]
    expect: str
    options: list[str] = field(default_factory=list)
    made_by: str = "solve_ivp (LSODA)"

    def write(self, path: Path) -> Path:
        names = list(self.columns)
        with path.open("w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(names + (["segment"] if self.labels is not None else []))
            n = self.columns["t"].size
            for k in range(n):
                row = []
                for c in names:
                    x = float(self.columns[c][k])
                    row.append("" if math.isnan(x) else f"{x:.10g}")
                if self.labels is not None:
                    row.append(self.labels[k])
                w.writerow(row)
        return path


# ---------------------------------------------------------------------------
# integration
# ---------------------------------------------------------------------------
def _rhs(p: Plant, s: Sensors, v: float, is_open: bool) -> Callable:
    w_c = 1e-3  # rad/s: the width of the friction's sign

    def f(_t: float, x: np.ndarray) -> np.ndarray:
        i, w, _th, temp, va, i_f, w_f = x
        r = p.R * (1.0 + 0.0039 * temp)
        dva = 0.0 if p.drive_tau_s <= 0 else (v - va) / p.drive_tau_s
        applied = v if p.drive_tau_s <= 0 else va
        di = -i / 1e-5 if is_open else (applied - r * i - p.Ke * w) / p.L
        fric = p.Tc * math.tanh(w / w_c) if p.Tc else 0.0
        dw = (p.Kt * i - p.B * w - fric) / p.J
        dtemp = p.heat_per_a2s * i * i - (temp / p.cool_s if math.isfinite(p.cool_s) else 0.0)
        dif = 0.0 if s.current_tau_s <= 0 else (i - i_f) / s.current_tau_s
        dwf = 0.0 if s.speed_tau_s <= 0 else (w - w_f) / s.speed_tau_s
        return np.array([di, dw, w, dtemp, dva, dif, dwf])

    return f


def integrate(
    p: Plant, s: Sensors, voltage: np.ndarray, rate_hz: float, *, seed: int = 0
) -> dict[str, np.ndarray]:
    """``voltage`` (V per sample, held over it; NaN = open armature) from rest.

    Returns the columns ``t, voltage, current, speed[, position]`` as measured.
    """
    from scipy.integrate import solve_ivp

    dt = 1.0 / rate_hz
    n = voltage.size
    t = np.arange(n) * dt
    x = np.zeros(7)
    state = np.empty((n, 7))
    edges = np.flatnonzero(np.diff(np.nan_to_num(voltage, nan=1e300)) != 0) + 1
    bounds = np.r_[0, edges, n]
    tau_min = min(p.L / p.R, 1e-3)
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        v = float(voltage[lo])
        is_open = math.isnan(v)
        f = _rhs(p, s, 0.0 if is_open else v, is_open)
        span = (t[lo], t[lo] + (hi - lo) * dt)
        sol = solve_ivp(
            f,
            span,
            x,
            method=METHOD,
            t_eval=np.r_[t[lo:hi], span[1]],
            rtol=1e-8,
            atol=1e-11,
            first_step=tau_min / 50,
        )
        if not sol.success:
            raise RuntimeError(sol.message)
        state[lo:hi] = sol.y[:, :-1].T
        x = sol.y[:, -1].copy()
        if is_open:
            x[0] = 0.0
    rng = np.random.default_rng(seed)
    i_meas = state[:, 5] if s.current_tau_s > 0 else state[:, 0]
    w_true = state[:, 6] if s.speed_tau_s > 0 else state[:, 1]
    out = {"t": t, "voltage": voltage.astype(float)}
    out["current"] = i_meas + rng.normal(0.0, s.current_sd, n)
    if s.speed_counts_per_rev:
        q = 2 * math.pi / s.speed_counts_per_rev
        counts = np.floor(state[:, 2] / q)
        out["speed"] = np.r_[0.0, np.diff(counts)] * q / dt
    else:
        out["speed"] = w_true + rng.normal(0.0, s.speed_sd, n)
    if s.position:
        out["position"] = state[:, 2]
    return out


def _join(parts: Sequence[dict[str, np.ndarray]], gap_s: float = 0.0) -> dict[str, np.ndarray]:
    """Runs recorded one after the other into one table: the clock runs on (each run's
    first sample one period after the previous run's last, plus ``gap_s``)."""
    out: dict[str, list[np.ndarray]] = {k: [] for k in parts[0]}
    t_next = 0.0
    for part in parts:
        dt = float(part["t"][1] - part["t"][0])
        for k, v in part.items():
            out[k].append(v - v[0] + t_next if k == "t" else v)
        t_next = float(out["t"][-1][-1]) + dt + gap_s
    return {k: np.concatenate(v) for k, v in out.items()}


def _hold(levels: Sequence[float], seconds: Sequence[float], rate_hz: float) -> np.ndarray:
    return np.concatenate(
        [np.full(int(round(s * rate_hz)), v) for v, s in zip(levels, seconds, strict=True)]
    )


def _prbs(n: int, amplitude: float, hold: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    bits = rng.integers(0, 2, size=n // hold + 1) * 2 - 1
    return np.repeat(bits * amplitude, hold)[:n].astype(float)


# ---------------------------------------------------------------------------
# the motors
# ---------------------------------------------------------------------------
SMALL_12V = Plant(R=2.0, L=1.0e-3, Ke=0.02, Kt=0.02, J=4.0e-6, B=1.0e-6)
# a coreless motor as in the Quanser Aero 2 (nominal R 8.2 ohm, L 1.16 mH)
CORELESS = Plant(R=8.2, L=1.16e-3, Ke=0.042, Kt=0.042, J=4.0e-6, B=2.0e-7, Tc=6e-4)
# 1.5 kW 48 V traction motor: 48 V at ~450 rad/s, stall 960 A
TRACTION = Plant(R=0.05, L=1.0e-4, Ke=0.1, Kt=0.1, J=0.02, B=2e-3)
FAST_L = Plant(R=1.0, L=2.0e-4, Ke=0.03, Kt=0.03, J=1.0e-5, B=2.0e-6)  # L/R 0.2 ms


def _runs(rate: float) -> list[tuple[str, np.ndarray]]:
    """Three separate experiments, each from rest: a step up, a step down, a PRBS."""
    rest = 0.05
    return [
        ("step_up", _hold([0.0, 6.0], [rest, 0.35], rate)),
        ("step_down", _hold([0.0, -6.0], [rest, 0.35], rate)),
        ("prbs", np.r_[np.zeros(int(rest * rate)), _prbs(int(0.6 * rate), 6.0, 10, seed=3)]),
    ]


def concatenated(rate: float = 1000.0, gap_s: float = 0.0, mujoco: bool = True) -> ForeignRecord:
    """Separate runs, each from rest, joined with a running clock (``gap_s`` = 0) or
    with time inserted between them; labelled by run. MuJoCo's dcmotor makes them."""
    parts, labels = [], []
    for k, (label, v) in enumerate(_runs(rate)):
        if mujoco:
            cols = mujoco_columns(SMALL_12V, v, rate, seed=10 + k)
        else:
            cols = integrate(SMALL_12V, Sensors(), v, rate, seed=10 + k)
        parts.append(cols)
        labels += [label] * v.size
    name = "concatenated_gaps" if gap_s else "concatenated"
    how = f"{gap_s:g} s inserted between runs" if gap_s else "a clock that runs on"
    return ForeignRecord(
        name,
        f"3 runs from rest (step up, step down, PRBS), {how}, labelled",
        _join(parts, gap_s),
        labels,
        SMALL_12V.truth(),
        "separate runs (continuity), diagnose no_gap, R/Ke/J within intervals",
        made_by="MuJoCo dcmotor" if mujoco else "solve_ivp (LSODA)",
    )


def position_restarts(rate: float = 1000.0) -> ForeignRecord:
    """Three runs forward from rest (6 V, 4 V, a 0/6 V PRBS) without labels; the
    position column restarts at 0 with each run (an encoder zeroed at every start)."""
    rest = int(0.05 * rate)
    runs = [
        _hold([0.0, 6.0], [0.05, 0.35], rate),
        _hold([0.0, 4.0], [0.05, 0.35], rate),
        np.r_[np.zeros(rest), 3.0 + _prbs(int(0.5 * rate), 3.0, 10, seed=3)],
    ]
    parts = [
        integrate(SMALL_12V, Sensors(position=True), v, rate, seed=20 + k)
        for k, v in enumerate(runs)
    ]
    cols = _join(parts)
    return ForeignRecord(
        "position_restarts",
        "3 runs forward from rest, no labels, position restarting at 0 with each run",
        cols,
        None,
        SMALL_12V.truth(),
        "no position-wrap finding; cut into runs at the restarts; within intervals",
    )


def index_time(rate: float = 1000.0) -> ForeignRecord:
    """One continuous session (steps both ways, a PRBS), written with t = index / fs
    and labelled: every boundary is a real continuation and must stay one."""
    v_parts = [
        ("step_up", _hold([0.0, 6.0], [0.05, 0.3], rate)),
        ("step_down", _hold([-6.0], [0.3], rate)),
        ("prbs", _prbs(int(0.6 * rate), 6.0, 25, seed=4)),
        ("step_up_2", _hold([3.0], [0.3], rate)),
    ]
    v = np.concatenate([x for _, x in v_parts])
    cols = integrate(SMALL_12V, Sensors(), v, rate, seed=30)
    labels = [lab for lab, x in v_parts for _ in range(x.size)]
    return ForeignRecord(
        "index_time",
        "one continuous session, t = index / fs, labelled (steps both ways, PRBS)",
        cols,
        labels,
        SMALL_12V.truth(),
        "every boundary a continuation; within intervals",
    )


def filtered_current_fast_l(rate: float = 1000.0) -> ForeignRecord:
    """L/R = 0.2 ms at 1 kHz, the current sensor behind a 1 ms RC filter."""
    v = np.r_[
        _hold([0.0, 8.0, -8.0, 4.0], [0.05, 0.25, 0.25, 0.2], rate),
        _prbs(int(0.5 * rate), 8.0, 20, seed=5),
    ]
    cols = integrate(FAST_L, Sensors(current_sd=0.003, current_tau_s=1e-3), v, rate, seed=40)
    return ForeignRecord(
        "filtered_current_fast_l",
        "L/R 0.2 ms sampled at 1 kHz, current through a 1 ms RC filter",
        cols,
        None,
        FAST_L.truth(),
        "L flagged with what to record; R, Ke, J within intervals or flagged",
    )


def step_500hz(mujoco: bool = True) -> ForeignRecord:
    """One 8 V step from rest at 500 Hz on a coreless motor, one direction."""
    rate = 500.0
    v = _hold([0.0, 8.0], [0.1, 1.4], rate)
    p = CORELESS
    cols = (
        mujoco_columns(p, v, rate, seed=50, frictionloss=CORELESS.Tc, current_sd=0.002)
        if mujoco
        else integrate(p, Sensors(current_sd=0.001), v, rate, seed=50)
    )
    return ForeignRecord(
        "step_500hz",
        "coreless motor, one 8 V step from rest at 500 Hz (one direction)",
        cols,
        None,
        p.truth(),
        "B flagged (one speed; gate and table one message); L flagged or within",
        made_by="MuJoCo dcmotor" if mujoco else "solve_ivp (LSODA)",
    )


def speed_lag(rate: float = 1000.0) -> ForeignRecord:
    """A tachogenerator with its own 4 ms lag (tau_m 20 ms)."""
    v = np.r_[_hold([0.0, 6.0, -6.0], [0.05, 0.3, 0.3], rate), _prbs(int(0.6 * rate), 6, 30, 6)]
    cols = integrate(SMALL_12V, Sensors(speed_tau_s=4e-3, speed_sd=0.1), v, rate, seed=60)
    return ForeignRecord(
        "speed_lag",
        "speed sensor with its own 4 ms lag (mechanical time constant 20 ms)",
        cols,
        None,
        SMALL_12V.truth(),
        "no confident-wrong parameter: each within its interval or flagged",
    )


def rest_first_level(rate: float = 500.0) -> ForeignRecord:
    """A staircase from rest whose first sample already carries 2 V, speed in whole
    counts of a 28-count encoder per sample (0.45 rad/s steps), a winding that heats."""
    p = Plant(R=1.2, L=3.0e-4, Ke=0.02, Kt=0.02, J=1.5e-6, B=5e-7, heat_per_a2s=8.0, cool_s=20.0)
    v = _hold([2.0, 4.0, 6.0, 8.0], [0.6, 0.6, 0.6, 0.6], rate)
    cols = integrate(p, Sensors(current_sd=0.004, speed_counts_per_rev=28), v, rate, seed=70)
    return ForeignRecord(
        "rest_first_level",
        "staircase from rest with 2 V already on at the first sample, 0.45 rad/s speed "
        "counts, winding heating",
        cols,
        None,
        p.truth(),
        "start read as rest; YAML accepted by export-model; no advice beyond hardware",
        options=["--speed-averaged"],
    )


def traction_48v(rate: float = 1000.0) -> ForeignRecord:
    """A 1.5 kW 48 V traction motor: a ramp to 38 V, then a +-10 V chirp on top, drawing
    ~200 A (at 48 V it runs at ~480 rad/s)."""
    ramp = np.linspace(0.0, 38.0, int(0.4 * rate))
    n = int(0.75 * rate)
    t = np.arange(n) / rate
    f0, f1 = 2.0, 40.0
    phase = 2 * np.pi * (f0 * t + 0.5 * (f1 - f0) / t[-1] * t**2)
    v = np.r_[np.zeros(int(0.05 * rate)), ramp, 38.0 + 10.0 * np.sin(phase)]
    cols = integrate(TRACTION, Sensors(current_sd=0.2, speed_sd=0.2), v, rate, seed=80)
    return ForeignRecord(
        "traction_48v",
        "1.5 kW 48 V traction motor (R 0.05 ohm), ramp and chirp drawing ~200 A",
        cols,
        None,
        TRACTION.truth(),
        "no current-unit refusal; within intervals",
    )


def staircase_one_segment(rate: float = 500.0) -> ForeignRecord:
    """An 8-level staircase recorded as one labelled segment."""
    levels = [1.5, 3.0, 4.5, 6.0, 7.5, 9.0, 10.5, 12.0]
    v = _hold(levels, [0.25] * 8, rate)
    p = Plant(R=2.0, L=1e-3, Ke=0.02, Kt=0.02, J=4e-6, B=1e-6, Tc=2e-3)
    cols = integrate(p, Sensors(), v, rate, seed=90)
    return ForeignRecord(
        "staircase_one_segment",
        "an 8-level staircase in one labelled segment",
        cols,
        ["staircase"] * v.size,
        p.truth(),
        "the 8 levels are found (no 'at least 3 steady levels, got 1')",
    )


def mujoco_columns(
    p: Plant,
    voltage: np.ndarray,
    rate_hz: float,
    *,
    seed: int,
    frictionloss: float = 0.0,
    current_sd: float = 0.01,
    speed_sd: float = 0.1,
) -> dict[str, np.ndarray]:
    """``voltage`` through MuJoCo's ``<dcmotor>`` (from rest), measured with noise: by
    default a 12-bit current sense on +-10 A (5 mA steps, 10 mA noise) and a
    tachogenerator's 0.1 rad/s. MuJoCo's own discretisation (Euler, 200 steps per
    sample) lags by half a step: L reads 0.34 % low (1.37 % at 50 steps, 0.07 % at 800),
    which only the sub-sample timing in L's interval covers."""
    from pmdc_ident.benchmark.mujoco_plant import DcMotor, simulate

    motor = DcMotor(R=p.R, L=p.L, K=p.Ke, J=p.J, B=p.B, frictionloss=frictionloss)
    cur, spd, _pos = simulate(motor, voltage, 1.0 / rate_hz)
    rng = np.random.default_rng(seed)
    n = voltage.size
    return {
        "t": np.arange(n) / rate_hz,
        "voltage": voltage.astype(float),
        "current": cur + rng.normal(0.0, current_sd, n),
        "speed": spd + rng.normal(0.0, speed_sd, n),
    }


def flagged(p: dict) -> bool:
    """A parameter of identify's JSON the tool does not claim: not identifiable, or its
    reason says weakly identifiable, assumed or fixed."""
    reason = str(p.get("reason") or "")
    return (not p.get("identifiable", True)) or reason.startswith(("weakly", "assumed", "fixed"))


def confident_wrong(params: dict, truth: dict[str, float]) -> list[str]:
    """Parameters of identify's JSON whose truth lies outside the reported 95 % interval
    by more than 3 standard errors while they are not flagged (issue 22's measure)."""
    out = []
    for name, true in truth.items():
        p = params.get(name)
        if p is None or flagged(p) or p.get("ci95") is None:
            continue
        lo, hi = p["ci95"]
        se = p.get("stderr") or (hi - lo) / (2 * 1.96)
        if true < lo - 3 * se or true > hi + 3 * se:
            out.append(f"{name} {p['value']:.4g} [{lo:.3g}, {hi:.3g}] (truth {true:.4g})")
    return out


_MAKERS: dict[str, Callable[[], ForeignRecord]] = {
    "concatenated": concatenated,
    "concatenated_gaps": lambda: concatenated(gap_s=1.0),
    "position_restarts": position_restarts,
    "index_time": index_time,
    "filtered_current_fast_l": filtered_current_fast_l,
    "step_500hz": step_500hz,
    "speed_lag": speed_lag,
    "rest_first_level": rest_first_level,
    "traction_48v": traction_48v,
    "staircase_one_segment": staircase_one_segment,
}


def record_by_name(name: str) -> ForeignRecord:
    return _MAKERS[name]()


def corpus() -> list[ForeignRecord]:
    return [make() for make in _MAKERS.values()]
