"""Is this motor still the one identified? Drift levels and a latched re-identify flag.

:class:`DriftMonitor` feeds samples (time, applied voltage, current, speed)
through :mod:`pmdc_ident.core.drift_estimator` and turns the estimates into
levels. Per quantity (resistance, back-EMF constant, friction torque, delay) the
drift from the identified value is compared with two thresholds at 95 %
confidence (one-sided: the estimate's lower bound against the threshold):

* the level rises when the drift is beyond a threshold with 95 % confidence,
  confirmed again ``hold_s`` later without being disproven in between: drift is
  claimed only where the data prove it, so a motor standing still (whose
  intervals widen) never raises one;
* it falls back when the drift is below the threshold with 95 % confidence;
  while the data are uninformative the last proven level stays.

The overall level is the worst one. A re-identification is suggested, and the
suggestion latched until :meth:`DriftMonitor.reset_suggestion`, when any level
reaches ERROR or stays at WARN for ``suggest_after_s``. The reset also starts the
estimates over from the identified values and the levels at OK, so the suggestion
latches again only on evidence gathered after it, never from the estimate that raised
it. Each restarted interval also admits the last estimate: the motor did not cool at
the reset, and an interval that excluded its hot R would push R's misfit onto Ke.
:func:`diagnostic_status` is what ``/diagnostics`` says: STALE before the first report
and whenever no driver sample came for a while. The winding temperature rise follows
from R with the copper coefficient: ``dT = (R/R0 - 1)/alpha``.

The delay's interval includes half a sample period: the current's path between
samples is not observed (on the simulator the estimate reads about 0.35 ms at
1 kHz for a motor without delay, L/R = 0.2 ms).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from pmdc_ident.core.drift_estimator import EstimatorTuning, new_state, run_estimator
from pmdc_ident.core.effects import CoulombFriction, Delay
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.motors import MotorSpec

__all__ = [
    "COPPER_COEFF_PER_K",
    "QUANTITIES",
    "STALE",
    "DriftLevel",
    "DriftMonitor",
    "DriftReport",
    "MonitorConfig",
    "QuantityEstimate",
    "diagnostic_status",
]

COPPER_COEFF_PER_K = 3.93e-3  # resistance temperature coefficient of copper at 20 degC
_Z95 = 1.959964  # two-sided 95 % interval (reported)
_Z95_ONE_SIDED = 1.644854  # "beyond the threshold" is a one-sided claim
# name -> (unit, column of the estimate, column of its variance)
QUANTITIES: dict[str, tuple[str, str, str]] = {
    "resistance": ("ohm", "R", "var_R"),
    "back_emf": ("V*s/rad", "Ke", "var_Ke"),
    "friction": ("N*m", "friction_nm", "var_friction"),
    "delay": ("s", "delay_s", "var_delay"),
}


class DriftLevel(enum.IntEnum):
    """Same numbers as diagnostic_msgs/DiagnosticStatus OK, WARN, ERROR."""

    OK = 0
    WARN = 1
    ERROR = 2


STALE = 3  # diagnostic_msgs/DiagnosticStatus.STALE: no data to judge the motor by


@dataclass(frozen=True)
class MonitorConfig:
    """Thresholds on the drift from the identified value (relative where noted).

    ``friction_*_nm`` 0 takes the identified friction torque (or 1 % of the rated
    torque Kt I_max if larger) as the WARN step and three times it as ERROR.
    """

    r_warn_rel: float = 0.10  # +10 % R: about +25 K of copper
    r_error_rel: float = 0.20
    ke_warn_rel: float = 0.05
    ke_error_rel: float = 0.10
    friction_warn_nm: float = 0.0
    friction_error_nm: float = 0.0
    delay_warn_s: float = 0.002
    delay_error_s: float = 0.010
    hold_s: float = 1.0
    suggest_after_s: float = 30.0
    report_period_s: float = 0.1
    prior_rel: float = 0.05  # prior standard deviation of the identified values
    copper_coeff_per_k: float = COPPER_COEFF_PER_K
    tuning: EstimatorTuning = field(default_factory=EstimatorTuning)

    def __post_init__(self) -> None:
        for name in ("r", "ke", "friction", "delay"):
            unit = "_nm" if name == "friction" else ("_s" if name == "delay" else "_rel")
            warn, err = getattr(self, f"{name}_warn{unit}"), getattr(self, f"{name}_error{unit}")
            if not (math.isfinite(warn) and math.isfinite(err) and 0 <= warn <= err):
                msg = f"{name} thresholds need 0 <= warn <= error, got {warn:g} and {err:g}"
                raise ParameterError(msg)
        for name in ("hold_s", "suggest_after_s", "report_period_s", "prior_rel"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                msg = f"monitor {name} must be a positive number, got {value}"
                raise ParameterError(msg)


@dataclass(frozen=True)
class QuantityEstimate:
    """One monitored quantity: estimate, 95 % half-interval, drift and its level."""

    name: str
    unit: str
    value: float
    ci95: float
    reference: float
    warn: float  # thresholds on |value - reference|, in the quantity's unit
    error: float
    level: DriftLevel
    excited: bool  # the interval is narrow enough to decide against the WARN threshold

    @property
    def drift(self) -> float:
        return self.value - self.reference


@dataclass(frozen=True)
class DriftReport:
    """The monitor's view at one instant."""

    t_s: float
    quantities: tuple[QuantityEstimate, ...]
    temperature_rise_k: float
    temperature_ci95_k: float
    level: DriftLevel
    suggest_reidentify: bool
    message: str

    def quantity(self, name: str) -> QuantityEstimate:
        return next(q for q in self.quantities if q.name == name)


class DriftMonitor:
    """Streaming drift monitor for one motor (see module doc)."""

    def __init__(self, spec: MotorSpec, config: MonitorConfig | None = None) -> None:
        self.spec = spec
        self.config = cfg = config or MonitorConfig()
        p = spec.model.params
        coulomb = spec.model.effect("coulomb_friction")
        delay = spec.model.effect("delay")
        tc = coulomb.torque_nm if isinstance(coulomb, CoulombFriction) else 0.0
        d0 = delay.delay_s if isinstance(delay, Delay) else 0.0
        rated = p.Kt * spec.limits.current_max_a
        f_warn = cfg.friction_warn_nm or max(tc, 0.01 * rated)
        f_err = cfg.friction_error_nm or 3.0 * f_warn
        self.reference = {"resistance": p.R, "back_emf": p.Ke, "friction": tc, "delay": d0}
        self.thresholds = {
            "resistance": (cfg.r_warn_rel * p.R, cfg.r_error_rel * p.R),
            "back_emf": (cfg.ke_warn_rel * p.Ke, cfg.ke_error_rel * p.Ke),
            "friction": (f_warn, f_err),
            "delay": (cfg.delay_warn_s, cfg.delay_error_s),
        }
        tn = cfg.tuning
        self._f_scale = max(tc, 0.01 * rated)
        self._prior_var = np.array(
            [
                (cfg.prior_rel * p.R) ** 2,
                (cfg.prior_rel * p.Ke) ** 2,
                (2.0 * cfg.delay_warn_s) ** 2,
            ]
        )
        self._prior_var_m = (2.0 * f_warn) ** 2
        self._prior = (np.array([p.R, p.Ke, d0]), self._prior_var, tc, self._prior_var_m)
        self._state = new_state(*self._prior)
        deadband = tn.speed_deadband_rad_s or 0.02 * spec.limits.speed_max_rad_s
        q_tf = (tn.friction_rate_nm or 0.01 * rated) ** 2
        self._consts = np.array(
            [
                p.L,
                p.J,
                p.B,
                p.Kt,
                p.Ke,
                tn.filter_tau_s,
                (tn.r_rate_rel * p.R) ** 2,
                (tn.ke_rate_rel * p.Ke) ** 2,
                tn.delay_rate_s**2,
                q_tf,
                tn.noise_time_s,
                deadband,
                tn.max_gap_s,
                *(4.0 * self._prior_var),
                4.0 * self._prior_var_m,
                _current_gate(spec, tn.filter_tau_s),
            ]
        )
        self._levels = dict.fromkeys(QUANTITIES, DriftLevel.OK)
        self._pending: dict[str, tuple[DriftLevel, float]] = {}
        self._warn_since: float | None = None
        self._suggest = False
        self._suggest_reason = ""
        self._next_report = -math.inf
        self._last_row: np.ndarray | None = None
        self._dt = 0.0

    # -- streaming -----------------------------------------------------------
    def process(
        self, t_s: ArrayLike, voltage_v: ArrayLike, current_a: ArrayLike, speed_rad_s: ArrayLike
    ) -> list[DriftReport]:
        """Feed a batch of samples (NaN voltage = open armature); reports due in it."""
        t = np.asarray(t_s, dtype=float).ravel()
        arrays = [np.asarray(x, dtype=float).ravel() for x in (voltage_v, current_a, speed_rad_s)]
        if any(a.size != t.size for a in arrays):
            msg = "monitor samples need equal lengths of time, voltage, current and speed"
            raise ParameterError(msg)
        self._adapt_filter(t)
        rows = run_estimator(self._state, t, *arrays, self._consts)
        reports = []
        for row in rows:
            if row[0] >= self._next_report:
                self._next_report = row[0] + self.config.report_period_s
                reports.append(self._report(row))
            self._last_row = row
        return reports

    def restart_filters(self) -> None:
        """The next sample starts a new run (the motor's state does not follow from the
        last one: core/continuity.py): the signal filters restart there, as after a gap
        in time; the parameter estimates carry on."""
        from pmdc_ident.core import drift_estimator

        self._state["st"][drift_estimator._INIT] = 0.0  # the estimator's 'initialised' flag

    def latest(self) -> DriftReport | None:
        """A report of the newest estimate (None before the first update)."""
        return None if self._last_row is None else self._report(self._last_row, update=False)

    @property
    def suggest_reidentify(self) -> bool:
        return self._suggest

    def reset_suggestion(self) -> None:
        """Clear the latched suggestion (after a re-identification) and start over: the
        estimates from the identified values, every level at OK. A drift must then be
        proven again on samples that come after the reset (``hold_s`` apart), so the
        suggestion cannot re-latch from the old estimate. Each interval is the prior's
        widened by the distance to the last estimate, so it admits both (see below)."""
        self._suggest = False
        self._suggest_reason = ""
        self._warn_since = None
        self._levels = dict.fromkeys(QUANTITIES, DriftLevel.OK)
        self._pending.clear()
        theta_e, var_e, theta_m, var_m = self._prior
        # The motor did not change at the reset: a prior that excludes what the monitor
        # has just measured (a hot winding's R back at the cold value +-5 %) would load
        # R's misfit onto Ke at the next operating point and "prove" a back-EMF drift
        # that is not there. So each estimate starts at its identified value with an
        # interval that also admits the last estimate (no drift can be proven from it).
        var_e = var_e + (self._state["th_e"] - theta_e) ** 2
        var_m = var_m + float(self._state["th_m"][0] - theta_m) ** 2
        fresh = new_state(theta_e, var_e, theta_m, var_m)  # the signal filters keep theirs
        for key in ("th_e", "p_e", "th_m", "p_m"):
            self._state[key][...] = fresh[key]
        # the random walk's caps must not clip that interval back at the next sample
        self._consts[13:16] = np.maximum(4.0 * self._prior_var, var_e)
        self._consts[16] = max(4.0 * self._prior_var_m, var_m)
        self._next_report = -math.inf

    # -- internals -----------------------------------------------------------
    def _adapt_filter(self, t: np.ndarray) -> None:  # noqa: D401
        """Keep the filter at least three sample periods long (slow logs)."""
        if t.size > 2:
            self._dt = float(np.median(np.diff(t)))
            self._consts[5] = max(self.config.tuning.filter_tau_s, 3.0 * self._dt)

    def _report(self, row: np.ndarray, update: bool = True) -> DriftReport:
        from pmdc_ident.core.drift_estimator import OUT_COLUMNS

        col = dict(zip(OUT_COLUMNS, row, strict=True))
        t = float(col["t_s"])
        quantities = []
        for name, (unit, key, var_key) in QUANTITIES.items():
            value, ci = float(col[key]), _Z95 * math.sqrt(max(float(col[var_key]), 0.0))
            if name == "delay":  # the current between samples is not seen: +-dt/2
                ci = math.hypot(ci, 0.5 * self._dt)
            warn, err = self.thresholds[name]
            level = self._level(name, value, ci, t) if update else self._levels[name]
            quantities.append(
                QuantityEstimate(
                    name, unit, value, ci, self.reference[name], warn, err, level, ci < warn / 2
                )
            )
        overall = max(q.level for q in quantities)
        if update:
            self._update_suggestion(overall, quantities, t)
        r0, alpha = self.reference["resistance"], self.config.copper_coeff_per_k
        rq = quantities[0]
        return DriftReport(
            t_s=t,
            quantities=tuple(quantities),
            temperature_rise_k=(rq.value / r0 - 1.0) / alpha,
            temperature_ci95_k=rq.ci95 / (r0 * alpha),
            level=DriftLevel(overall),
            suggest_reidentify=self._suggest,
            message=self._message(quantities, DriftLevel(overall)),
        )

    def _level(self, name: str, value: float, ci: float, t: float) -> DriftLevel:
        drift = abs(value - self.reference[name])
        warn, err = self.thresholds[name]
        half = ci * _Z95_ONE_SIDED / _Z95
        low, high = drift - half, drift + half
        current = self._levels[name]
        proven = DriftLevel.OK
        if low > err:
            proven = DriftLevel.ERROR
        elif low > warn:
            proven = DriftLevel.WARN
        floor = {DriftLevel.OK: 0.0, DriftLevel.WARN: warn, DriftLevel.ERROR: err}
        # A higher level is taken when proven twice, hold_s apart, and not disproven
        # in between (uninformative data in between neither confirm nor cancel it).
        pending = self._pending.get(name)
        if pending is not None and high < floor[pending[0]]:
            pending = None
        if proven > current:
            if pending is None or proven < pending[0]:
                pending = (proven, t)
            elif t - pending[1] >= self.config.hold_s:
                self._levels[name] = pending[0]
                pending = None
        if pending is None:
            self._pending.pop(name, None)
        else:
            self._pending[name] = pending
        # falls back only when the drift is below the level's threshold with confidence
        current = self._levels[name]
        if current > DriftLevel.OK and high < floor[current]:
            self._levels[name] = max(proven, DriftLevel(current - 1))
        return self._levels[name]

    def _update_suggestion(self, overall: int, quantities: list, t: float) -> None:
        if overall >= DriftLevel.WARN:
            self._warn_since = t if self._warn_since is None else self._warn_since
        else:
            self._warn_since = None
        if self._suggest:
            return
        worst = max(quantities, key=lambda q: q.level)
        held = self._warn_since is not None and t - self._warn_since >= self.config.suggest_after_s
        if overall >= DriftLevel.ERROR or held:
            self._suggest = True
            self._suggest_reason = (
                f"{worst.name} {worst.value:.4g} {worst.unit} vs identified "
                f"{worst.reference:.4g} {worst.unit} (t = {t:.1f} s)"
            )

    def _message(self, quantities: list, overall: DriftLevel) -> str:
        if overall == DriftLevel.OK and not self._suggest:
            return "motor matches its identified model"
        bad = [f"{q.name} {q.level.name}" for q in quantities if q.level > DriftLevel.OK]
        text = ", ".join(bad) if bad else "levels back to OK"
        if self._suggest:
            text += f"; re-identify suggested: {self._suggest_reason}"
        return text


def diagnostic_status(
    report: DriftReport | None, since_sample_s: float | None, stale_after_s: float
) -> tuple[int, str]:
    """The ``/diagnostics`` level (0-3, :data:`STALE` = 3) and message: STALE before the
    first report, and when no driver sample came for ``stale_after_s`` (the last level
    is named in the message: it describes the motor as it was), else the report's."""
    if report is None:
        return STALE, "no driver samples yet"
    if since_sample_s is not None and since_sample_s > stale_after_s:
        return STALE, (
            f"no driver samples for {since_sample_s:.1f} s; last report "
            f"{report.level.name}: {report.message}"
        )
    return int(report.level), report.message


def _current_gate(spec: MotorSpec, tau_s: float) -> float:
    """Filtered current that stands out of the sensor noise (or 0.2 % of I_max)."""
    noise = spec.sensors.current_noise_a
    return max(10.0 * noise * math.sqrt(1e-3 / (2.0 * tau_s)), 0.002 * spec.limits.current_max_a)
