"""Expected parameter uncertainty before the fit: the Cramer-Rao bound on these data.

The planned model (the seeds' linear motor plus a Coulomb torque, ``Kt = Ke``;
with one direction of rotation the Coulomb term is the sum of friction and a
constant load) is linearised at a quick least-squares look at the record
(:mod:`regress`); output-error sensitivities of current and speed (or position)
come from exact ZOH simulations (:mod:`linsim`), each driven or open-armature
stretch from its own initial state (nuisance parameters, as the fit treats
them); the noise levels are the record's own (second differences). The inverse
information matrix gives each parameter's relative standard deviation.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.params import NEEDED_PARAMETERS
from pmdc_ident.core.quality.linsim import zoh, zoh_response
from pmdc_ident.core.quality.noise import signal_noise
from pmdc_ident.core.quality.regress import dynamic, electrical_fit, mechanical_fit
from pmdc_ident.core.quality.timing import time_constants_s

__all__ = [
    "HARDWARE_MAX_HZ",
    "TIMING_SHARE",
    "Information",
    "expected_information",
    "rate_for_inductance_hz",
]

# The fastest current sampling a motor drive offers: advice never names a rate above it
# (an LCR meter is the way to L then).
HARDWARE_MAX_HZ = 100e3
# Sub-sample timing no record can show (the voltage update and the current's sampling
# against the sample instants), as a share of the sample period: an offset reads as an
# L changed by about offset / (L/R), so it enters L's expected sd here and L's interval
# after the fit (core/identification/fit_checks.py), the same figure in both.
TIMING_SHARE = 0.01

FloatArray = NDArray[np.float64]
_LOG = ("R", "L", "Ke", "J")  # perturbed relatively; B and Tc absolutely
_STEP = 1e-6


@dataclass(frozen=True)
class Information:
    """Expected relative standard deviations of the planned model's parameters."""

    values: dict[str, float]
    rsd: dict[str, float]
    noise: dict[str, float]
    one_direction: bool
    tau_e_resolved: bool
    tau_m_resolved: bool
    dt_s: float
    notes: tuple[str, ...] = field(default=())


@dataclass
class _Piece:
    kind: str  # "driven" (voltage), "open" (armature open), "current" (current-driven)
    dt: float
    u: FloatArray  # (n, inputs)
    x0: FloatArray
    outputs: tuple[int, ...]  # state indices measured
    weights: tuple[float, ...]  # 1 / sigma per output


def _system(kind: str, p: Mapping[str, float]) -> tuple[FloatArray, FloatArray]:
    """``(A, B)``: driven states [i, w, th], inputs [V, s]; else states [w, th]."""
    r, ind, ke, j, b, tc = p["R"], p["L"], p["Ke"], p["J"], p["B"], p["Tc"]
    kt = ke
    if kind == "driven":
        a = np.array([[-r / ind, -ke / ind, 0.0], [kt / j, -b / j, 0.0], [0.0, 1.0, 0.0]])
        bm = np.array([[1.0 / ind, 0.0], [0.0, -tc / j], [0.0, 0.0]])
        return a, bm
    a = np.array([[-b / j, 0.0], [1.0, 0.0]])
    if kind == "open":
        return a, np.array([[-tc / j], [0.0]])
    return a, np.array([[kt / j, -tc / j], [0.0, 0.0]])


def _pieces(segments: Sequence[Segment], sigma: Mapping[str, float]) -> list[_Piece]:
    out: list[_Piece] = []
    for s in dynamic(segments):
        w = s.speed_or_derivative()
        sgn = np.sign(w)
        th = s.position if s.position is not None else np.zeros(s.n)
        w_out = 1 if s.speed is not None else 2  # speed, else position
        if s.voltage is None:
            if s.current is None:
                continue
            u = np.column_stack([s.current, sgn])
            out.append(
                _Piece(
                    "current",
                    s.dt_s,
                    u,
                    np.array([w[0], th[0]]),
                    (w_out - 1,),
                    (1.0 / sigma["speed" if w_out == 1 else "position"],),
                )
            )
            continue
        is_open = s.open_mask
        edges = np.flatnonzero(np.diff(is_open.astype(int))) + 1
        for lo, hi in zip(np.r_[0, edges], np.r_[edges, s.n], strict=True):
            if hi - lo < 3:
                continue
            if is_open[lo]:
                out.append(
                    _Piece(
                        "open",
                        s.dt_s,
                        sgn[lo:hi, None],
                        np.array([w[lo], th[lo]]),
                        (w_out - 1,),
                        (1.0 / sigma["speed" if w_out == 1 else "position"],),
                    )
                )
            elif s.current is not None:
                u = np.column_stack([s.voltage[lo:hi], sgn[lo:hi]])
                out.append(
                    _Piece(
                        "driven",
                        s.dt_s,
                        u,
                        np.array([s.current[lo], w[lo], th[lo]]),
                        (0, w_out),
                        (
                            1.0 / sigma["current"],
                            1.0 / sigma["speed" if w_out == 1 else "position"],
                        ),
                    )
                )
    return out


def _simulate(piece: _Piece, p: Mapping[str, float]) -> FloatArray:
    a, b = _system(piece.kind, p)
    phi, gam = zoh(a, b, piece.dt)
    c = np.eye(a.shape[0])[list(piece.outputs)]
    y = zoh_response(phi, gam, c, piece.u, piece.x0)
    return y * np.asarray(piece.weights)


def _initial_columns(piece: _Piece, p: Mapping[str, float]) -> list[FloatArray]:
    a, b = _system(piece.kind, p)
    phi, gam = zoh(a, b, piece.dt)
    c = np.eye(a.shape[0])[list(piece.outputs)]
    zero = np.zeros_like(piece.u)
    cols = []
    for k in range(a.shape[0]):
        e = np.zeros(a.shape[0])
        e[k] = 1.0
        cols.append((zoh_response(phi, gam, c, zero, e) * np.asarray(piece.weights)).ravel())
    return cols


def _start(segments: Sequence[Segment], fixed: Mapping[str, float]) -> dict[str, float] | None:
    """Parameter values to linearise at (``Kt = Ke``), from the quick regressions."""
    el = electrical_fit(segments)
    w = np.concatenate([s.speed_or_derivative() for s in dynamic(segments)])
    one_dir = bool(np.all(w >= -0.02 * np.max(np.abs(w))) or np.all(w <= 0.02 * np.max(np.abs(w))))
    mech = mechanical_fit(segments, coulomb=not one_dir)
    if mech is None:
        return None
    p: dict[str, float] = {}
    if el is not None:
        p["R"], p["Ke"] = el["R"], el["Ke"]
    p.update({k: v for k, v in fixed.items() if k in ("R", "L", "Ke", "J", "B")})
    ke = p.get("Ke", fixed.get("Kt", 1.0))
    p.setdefault("Ke", ke)
    if mech["a"] <= 0 or p["Ke"] <= 0 or p.get("R", 1.0) <= 0:
        return None
    p.setdefault("R", 1.0)
    tau_e, tau_m = time_constants_s(segments)
    dt = float(np.median([s.dt_s for s in dynamic(segments)]))
    p["_resolved"] = float(tau_e is not None)
    p["_j_resolved"] = float(tau_m is not None or "J" in fixed)
    if tau_m is not None:
        j_mech = p["Ke"] / mech["a"]
        b_qs, t_qs = _quasi_static_friction(segments, p["Ke"], one_dir)
        j_tau = tau_m * (p["Ke"] ** 2 / p["R"] + max(b_qs, 0.0))
        if 0.5 < j_mech / j_tau < 2.0:
            p.setdefault("J", j_mech)
            p.setdefault("B", mech["b"] * p["J"])
            torque = mech["c"] if not one_dir else mech["d"] * float(np.sign(np.mean(w)))
        else:
            # current and speed move together (one held voltage, L/R below a sample): the
            # regression is ill-posed; the speed's own time constant and the steady state
            # give the point to linearise at
            p.setdefault("J", j_tau)
            p.setdefault("B", b_qs)
            torque = t_qs / p["J"]
    else:  # the speed settles within a sample: steady state Ke i = B w + T at each sample
        b, torque = _quasi_static_friction(segments, p["Ke"], one_dir)
        p.setdefault("B", b)
        # placed where it has no effect (reported as not resolved)
        p.setdefault("J", (dt / 30.0) * (p["Ke"] ** 2 / p["R"] + max(p["B"], 0.0)))
    p["Tc"] = torque * (p["J"] if tau_m is not None else 1.0)
    # unresolved: the current settles within a sample; placed where it has no effect
    p.setdefault("L", p["R"] * (tau_e if tau_e is not None else dt / 30.0))
    # keep the linearisation point well-posed (B may come out ~0 or slightly negative)
    p["B"] = max(p["B"], 1e-4 * p["Ke"] ** 2 / p["R"])
    p["_one_dir"] = float(one_dir)
    cur = [s.current for s in dynamic(segments) if s.current is not None]
    p["_i_rms"] = float(np.sqrt(np.mean(np.concatenate(cur) ** 2))) if cur else 1.0
    return p


def _quasi_static_friction(
    segments: Sequence[Segment], ke: float, one_dir: bool
) -> tuple[float, float]:
    """``Ke i = B w + T`` over the samples (rotor in steady state at every sample)."""
    rows, ys = [], []
    for s in dynamic(segments):
        if s.current is None:
            continue
        w = s.speed_or_derivative()
        keep = ~s.open_mask
        sgn = np.ones_like(w) if one_dir else np.sign(w)
        rows.append(np.column_stack([w, sgn])[keep])
        ys.append(ke * s.current[keep])
    coef, *_ = np.linalg.lstsq(np.vstack(rows), np.concatenate(ys), rcond=None)
    return float(coef[0]), float(coef[1]) * (float(np.sign(np.mean(w))) if one_dir else 1.0)


def expected_information(
    segments: Sequence[Segment], fixed: Mapping[str, float] | None = None
) -> Information | None:
    """Expected relative sd of each free parameter on ``segments``; ``None`` if not posed."""
    fixed = dict(fixed or {})
    dyn = dynamic(segments)
    if not dyn:
        return None
    p = _start(dyn, fixed)
    if p is None:
        return None
    sigma = _noise(dyn)
    pieces = _pieces(dyn, sigma)
    if not pieces:
        return None
    drives = any(pc.kind == "driven" for pc in pieces)
    names = [n for n in ("R", "L", "Ke", "J", "B", "Tc") if n not in fixed]
    if not p["_resolved"] and "L" not in fixed:
        names.remove("L")  # reported as not identifiable below
    if not p["_j_resolved"] and "J" in names:
        names.remove("J")
    if not drives:
        names = [n for n in names if n in ("J", "B", "Tc")]
    base = [_simulate(pc, p) for pc in pieces]
    blocks: list[FloatArray] = []
    for k, pc in enumerate(pieces):
        cols = []
        for n in names:
            q = dict(p)
            h = _STEP * (p[n] if n in _LOG else max(abs(p[n]), _scale(n, p)))
            q[n] = p[n] + h
            d = (_simulate(pc, q) - base[k]) / h
            cols.append(d.ravel() * (p[n] if n in _LOG else 1.0))
        cols += _initial_columns(pc, p)
        blocks.append(np.column_stack(cols))
    info = _information(blocks, len(names))
    if info is None:
        return None
    cov = np.linalg.pinv(info)
    sd = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    rsd = {}
    for k, n in enumerate(names):
        rsd[n] = float(sd[k]) if n in _LOG else float(sd[k] / max(abs(p[n]), 1e-300))
    if not p["_resolved"] and "L" not in fixed and drives:
        rsd["L"] = math.inf
    elif "L" in rsd:  # the sub-sample timing no record shows
        rsd["L"] = math.hypot(
            rsd["L"], TIMING_SHARE * float(np.median([s.dt_s for s in dyn])) / (p["L"] / p["R"])
        )
    if not p["_j_resolved"]:
        rsd["J"] = math.inf
    values = {k: v for k, v in p.items() if not k.startswith("_")}
    return Information(
        values,
        rsd,
        sigma,
        bool(p["_one_dir"]),
        bool(p["_resolved"]),
        bool(p["_j_resolved"]),
        float(np.median([s.dt_s for s in dyn])),
    )


def _scale(name: str, p: Mapping[str, float]) -> float:
    """Absolute perturbation scale of B and Tc (they may be near zero)."""
    if name == "B":
        return 1e-2 * p["Ke"] ** 2 / p["R"]
    return 1e-2 * p["Ke"] * p["_i_rms"]


def _noise(segments: Sequence[Segment]) -> dict[str, float]:
    """Per-sample noise of each signal (:mod:`.noise`; position without the ARX step)."""

    def level(name: str) -> float:
        sd = signal_noise(segments, lambda s: getattr(s, name), arx=name != "position")
        return 1.0 if sd is None else sd

    return {"current": level("current"), "speed": level("speed"), "position": level("position")}


def _information(blocks: list[FloatArray], n_par: int) -> FloatArray | None:
    """Parameter information with each piece's initial state profiled out (Schur)."""
    info = np.zeros((n_par, n_par))
    for blk in blocks:
        g = blk.T @ blk
        a, b, c = g[:n_par, :n_par], g[:n_par, n_par:], g[n_par:, n_par:]
        info += a - b @ np.linalg.pinv(c) @ b.T
    if not np.all(np.isfinite(info)):
        return None
    return info


def rate_for_inductance_hz(rsd_now: float, tau_e_s: float, dt_s: float, target: float) -> float:
    """Sample rate at which L's relative sd falls to ``target`` (same noise per sample).

    When the current's transient after a voltage step spans samples, L's information
    is ``sum_k (k h / tau)^2 exp(-2 k h / tau)`` per edge: it grows as 1/h once the
    transient is resolved and vanishes when it settles within a sample. When it
    settles far inside a sample (h > 8 tau) that term is nil and what is left - the
    current's lag behind the back-EMF while the speed changes - grows only with the
    number of samples: the sd falls as sqrt(h), until two samples per L/R resolve the
    transient itself.
    """
    if not (math.isfinite(rsd_now) and rsd_now > 0):
        return math.inf
    if rsd_now <= target:
        return 1.0 / dt_s
    if dt_s > 8.0 * tau_e_s:
        # ... until the transient itself spans samples (two per L/R), where it takes over
        q = rsd_now / target  # q * q: inf past the float range, where ** 2 raises
        return min(q * q / dt_s, 2.0 / tau_e_s)

    def g(h: float) -> float:
        x = h / tau_e_s
        a = math.exp(-2.0 * x)
        return x * x * a * (1.0 + a) / (1.0 - a) ** 3

    base = g(dt_s)
    rate = 1.0 / dt_s
    for _ in range(200):
        if rsd_now * math.sqrt(base / g(1.0 / rate)) <= target:
            return rate
        rate *= 1.1
    return math.inf


# What pins each parameter down, when the data do not.
_ADVICE = {
    "R": "record a step from rest (the current's first peak is V/R) or a locked-rotor "
    "test, or {fix} R=... from a multimeter",
    "Ke": "record steady speeds at several voltages (a staircase)",
    "J": "record a step from rest or a coast-down with the armature open, sampled well "
    "inside the mechanical time constant",
    "B": "record steady speeds over a wider speed range, or a long coast-down",
    "Tc": "record slow speeds in both directions (a slow reversal or a staircase through zero)",
}
_NAMES = {"Tc": "coulomb_friction.torque_nm"}
WEAK, NOT_IDENTIFIABLE = 0.10, 0.50
_UNRESOLVED = {"L": "L/R", "J": "the mechanical time constant"}


def _advice(name: str, info: Information) -> str:
    if name == "J" and not info.tau_m_resolved:
        return (
            f"the speed settles within a sample at {1 / info.dt_s:.4g} Hz: sample at least "
            f"10x faster (>= {10 / info.dt_s:.4g} Hz), or add a known inertia to slow it"
        )
    if name != "L":
        return _ADVICE.get(name, "").format(fix=opt("fix"))
    tau = info.values["L"] / info.values["R"]
    if not info.tau_e_resolved:
        if 10 / info.dt_s > HARDWARE_MAX_HZ:
            return (
                f"the current settles within a sample at {1 / info.dt_s:.4g} Hz: "
                f"{opt('fix')} L=... from an LCR meter"
            )
        return (
            f"the current settles within a sample at {1 / info.dt_s:.4g} Hz: sample at least "
            f"10x faster (>= {10 / info.dt_s:.4g} Hz) or {opt('fix')} L=... from an LCR meter"
        )
    rate = rate_for_inductance_hz(info.rsd["L"], tau, info.dt_s, WEAK)
    where = f"sample at >= {rate:.3g} Hz (the bound drops below 10 % there)"
    if not math.isfinite(rate):
        where = "record sharper voltage steps"
    elif rate > HARDWARE_MAX_HZ:
        return f"{opt('fix')} L=... from an LCR meter (no drive samples its current fast enough)"
    return f"{where}, or {opt('fix')} L=... from an LCR meter"


def advice_for(name: str, rsd: float, *, tau_e: float, dt_s: float) -> str:
    """What would pin ``name`` down, given its relative sd now (the fit's or the gate's)."""
    if name != "L":
        key = name.split(".")[0].replace("coulomb_friction", "Tc")
        return _ADVICE.get(key, "").format(fix=opt("fix"))
    if not (math.isfinite(tau_e) and tau_e > 0):
        return f"fix L from an LCR meter ({opt('fix')} L=...)"
    rate = math.inf
    if math.isfinite(rsd) and math.exp(-1.96 * rsd) > 0.0:  # else as unbounded as inf
        # The rate must pin down every L the data allow, down to the low end of its 95 %
        # interval (L is fitted in log: L exp(-1.96 rsd)), not the estimate alone: an L
        # the data do not bound (relative sd 87 % on L/R = 0.7 us, fitted 5x too large)
        # was promised 10 % at 75 kHz, which resolves only the estimate; 10 % of the
        # smallest L it allows needs 2.3 MHz, beyond any drive.
        low = math.exp(-1.96 * rsd)
        rate = rate_for_inductance_hz(rsd / low, tau_e * low, dt_s, WEAK)
    if math.isfinite(rate) and rate > 1.0 / dt_s * 1.01:
        where = f"sample at >= {_hz(rate)} (the bound drops below 10 % there)"
    elif math.isfinite(rate):
        where = "record more or sharper voltage steps"
    else:
        rate = 10.0 / tau_e
        where = f"sample at >= {_hz(rate)} (10 samples per L/R)"
    if rate > HARDWARE_MAX_HZ:  # no drive samples that fast: only the meter is advice
        return (
            f"fix L from an LCR meter ({opt('fix')} L=...): no drive samples its current fast "
            "enough"
        )
    return f"{where}, or fix L from an LCR meter ({opt('fix')} L=...)"


def _hz(rate: float) -> str:
    return f"{rate / 1e3:.3g} kHz" if rate >= 1e3 else f"{rate:.3g} Hz"


def information_findings(where: str, segments: Sequence[Segment], fixed: Mapping[str, float]):
    """The expected-sd line and one line per weakly or not identifiable parameter."""
    from pmdc_ident.core.quality.findings import Finding, Severity

    info = expected_information(segments, fixed)
    if info is None:
        return [], {}
    model = "linear + Coulomb" if not info.one_direction else "linear + (friction + load)"
    noise = ", ".join(f"{k} {v:.3g}" for k, v in info.noise.items() if k != "position" or v != 1.0)
    listed = ", ".join(
        f"{_NAMES.get(k, k)} {100 * v:.2g} %" if math.isfinite(v) else f"{k} unresolved"
        for k, v in info.rsd.items()
    )
    out = [
        Finding(
            "expected-rsd",
            Severity.INFO,
            where,
            f"expected relative sd before the fit (Cramer-Rao bound of the {model} model, "
            f"Kt = Ke, on these data; noise per sample {noise}): {listed}",
        )
    ]
    for name, rsd in info.rsd.items():
        if rsd <= WEAK:
            continue
        label = _NAMES.get(name, name)
        if name == "Tc" and info.one_direction:
            label = "friction + load torque (one term: one direction)"
        bad = rsd > NOT_IDENTIFIABLE
        if math.isfinite(rsd):
            text = f"{label}: expected relative sd {rsd:.0%} on these data: " + (
                "not identifiable" if bad else "weakly identifiable"
            )
            severity = Severity.WARNING if bad else Severity.INFO
            if bad and name in NEEDED_PARAMETERS:
                # a prediction: the fit's own bound decides (it can be tighter than this)
                text += " (identify refuses the result if its fit's bound agrees)"
        else:
            # the samples do not resolve the time constant: only indirect effects (the
            # current's lag behind the back-EMF, the speed's average response) remain,
            # which the fit's own bound weighs; the gate cannot linearise at an unknown one
            text = (
                f"{label}: {_UNRESOLVED.get(name, name)} is not resolved at this rate: at "
                "best weakly identifiable, through indirect effects (the fit's bound says)"
            )
            severity = Severity.INFO
        out.append(
            Finding("identifiability", severity, where, text, _advice(name, info), value=rsd)
        )
    return out, info.rsd
