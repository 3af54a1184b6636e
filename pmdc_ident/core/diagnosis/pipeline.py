"""``diagnose``: baseline, localization, candidate search, verdict (ROS-free).

:func:`diagnose` is a short sequence of named steps:

1. the segments (labels made unique), the held-out split and the noise levels;
2. the baseline: the linear model fitted on the fit segments, L placed by simulation
   (or held where the data cannot resolve L/R);
3. where the baseline's held-out gap lies (regimes, periodicity in the shaft angle);
4. every testable candidate effect fitted alone and scored on the held-out segments;
5. the choice: the best significant candidate, ties named, greedy combinations while
   most of the gap remains;
6. the verdict, the gap shrink per regime and the assumptions made.
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from pmdc_ident.core.data import Run, Segment, check_excitation, unique_labels
from pmdc_ident.core.diagnosis.candidates import (
    DataScales,
    data_scales,
    fit_model,
    predict,
    scan_start,
)
from pmdc_ident.core.diagnosis.holdout import HoldoutSplit, split_segments
from pmdc_ident.core.diagnosis.localization import Localization, localize, regime_masks
from pmdc_ident.core.diagnosis.results import (
    CandidateScore,
    DiagnosisResult,
    RegimeShrink,
    Tie,
    Verdict,
    VerdictStatus,
)
from pmdc_ident.core.diagnosis.scoring import NoiseModel, Residuals, estimate_noise, residuals
from pmdc_ident.core.diagnosis.verdict import (
    Thresholds,
    order_tie,
    separating_test,
)
from pmdc_ident.core.effects import EFFECT_NAMES
from pmdc_ident.core.errors import DataError, ParameterError
from pmdc_ident.core.estimate import ParameterEstimate, estimate_from_fit
from pmdc_ident.core.estimators.output_error import FitResult, Prediction
from pmdc_ident.core.estimators.start import equation_error_start
from pmdc_ident.core.model import Model
from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams
from pmdc_ident.core.progress import ProgressCallback

__all__ = ["DiagnosisConfig", "diagnose"]

SLOW_SAMPLE_S = 0.01  # median sample period from which data count as steady-state tables
_FIT_ERRORS = (ValueError, ArithmeticError, np.linalg.LinAlgError)


@dataclass(frozen=True)
class DiagnosisConfig:
    """What the diagnosis tries and how it decides.

    ``holdout``: segment labels to hold out (default: the split of
    :mod:`~pmdc_ident.core.diagnosis.holdout`). ``effects``: the vocabulary to
    try. ``fixed``: parameters held at known values (e.g. ``{"L": 3e-4}`` from an
    LCR meter). ``initial``: starting parameters (e.g. from ``identify``).
    """

    holdout: tuple[str, ...] = ()
    effects: tuple[str, ...] = EFFECT_NAMES
    max_effects: int = 3
    fixed: Mapping[str, float] = field(default_factory=dict)
    initial: MotorParams | None = None
    max_nfev: int = 30
    workers: int = 2
    thresholds: Thresholds = field(default_factory=Thresholds)

    def __post_init__(self) -> None:
        unknown = [e for e in self.effects if e not in EFFECT_NAMES]
        if unknown:
            msg = f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(EFFECT_NAMES)}"
            raise ParameterError(msg)
        bad = [k for k in self.fixed if k not in PARAMETER_NAMES]
        if bad:
            msg = f"only motor parameters {PARAMETER_NAMES} can be fixed, not {', '.join(bad)}"
            raise ParameterError(msg)
        if self.max_effects < 1 or self.workers < 1 or self.max_nfev < 1:
            msg = "max_effects, workers and max_nfev must be >= 1"
            raise ParameterError(msg)
        object.__setattr__(self, "holdout", tuple(self.holdout))
        object.__setattr__(self, "effects", tuple(self.effects))


def diagnose(
    runs_or_segments: object,
    *,
    config: DiagnosisConfig | None = None,
    progress: ProgressCallback | None = None,
) -> DiagnosisResult:
    """Diagnose the sim-to-real gap of recorded runs (see the module notes)."""
    cfg = config or DiagnosisConfig()
    t_start = time.perf_counter()
    segments = _flatten(runs_or_segments)
    check_excitation(segments)  # a flat record: one line, not a singular fit
    split = split_segments(segments, cfg.holdout or None)
    noise = estimate_noise(segments)
    search = _Search(split, noise, cfg, progress)
    slow_note = _hold_inductance_for_tables(search, segments)
    search.say(
        f"{len(split.fit)} fit / {len(split.held_out)} held-out segments ({split.rule} split)"
    )
    base = _baseline(search)
    masks = regime_masks(split.held_out, base.fit.model.params.mechanical_time_constant_s)
    loc = localize(split.held_out, base.res, masks)
    scoring = _Scoring.for_baseline(base, noise, cfg.thresholds)
    untestable, singles = _single_candidates(search, base, loc)
    choice = _choose(search, scoring, base, singles)
    verdict = _verdict(choice, scoring)
    final = choice.chosen if verdict.status is VerdictStatus.EXPLAINED else base
    return DiagnosisResult(
        verdict=verdict,
        split=split,
        gap_before=scoring.g0,
        gap_after=final.gap,
        gap_by_signal_before=base.res.gap_by_signal(),
        gap_by_signal_after=final.res.gap_by_signal(),
        rms_before=base.res.rms_by_signal(),
        rms_after=final.res.rms_by_signal(),
        noise_sigma=dict(noise.sigma),
        localization=loc,
        candidates=tuple(sorted(choice.scores, key=lambda s: s.penalized_gap)),
        baseline=_estimates(base.fit, cfg.fixed),
        augmented=_estimates(final.fit, cfg.fixed),
        regimes=_regimes(masks, base, final),
        assumptions=_assumptions(search, slow_note, scoring.penalty, untestable),
        elapsed_s=time.perf_counter() - t_start,
        n_samples=sum(s.n for s in segments),
        held_out=split.held_out,
        predictions_before=tuple(_predictions(base.fit, split.held_out)),
        predictions_after=tuple(_predictions(final.fit, split.held_out)),
    )


# ---------------------------------------------------------------------------
# 1. segments
# ---------------------------------------------------------------------------
def _flatten(runs_or_segments: object) -> list[Segment]:
    items: list[object]
    if isinstance(runs_or_segments, (Run, Segment)):
        items = [runs_or_segments]
    else:
        try:
            items = list(runs_or_segments)  # type: ignore[call-overload]
        except TypeError:
            msg = "diagnose needs a Run, a Segment or a sequence of them"
            raise DataError(msg) from None
    segs: list[Segment] = []
    for it in items:
        if isinstance(it, Run):
            segs += list(it.segments)
        elif isinstance(it, Segment):
            segs.append(it)
        else:
            msg = f"diagnose needs Runs or Segments, got {type(it).__name__}"
            raise DataError(msg)
    if not segs:
        msg = "no segments to diagnose"
        raise DataError(msg)
    out = unique_labels(segs)
    if not any(s.current is not None for s in out):
        msg = "the diagnosis needs a current column in at least one segment"
        raise DataError(msg)
    if not any(s.voltage is not None and np.isfinite(s.voltage).any() for s in out):
        msg = "the diagnosis needs a voltage column with driven samples"
        raise DataError(msg)
    return out


# ---------------------------------------------------------------------------
# 2. the baseline
# ---------------------------------------------------------------------------
def _hold_inductance_for_tables(search: _Search, segments: Sequence[Segment]) -> str:
    """Tables of steady states (seconds apart) show no electrical dynamics; a free L
    would run off to freeze the current at its measured start value: hold it."""
    cfg = search.cfg
    dt_med = float(np.median([s.dt_s for s in segments]))
    if "L" in search.fixed or dt_med < SLOW_SAMPLE_S:
        return ""
    p_tmp = cfg.initial or equation_error_start(search.split.fit, cfg.fixed)
    search.fixed["L"] = p_tmp.R * dt_med * 0.01
    return (
        f"L held at {search.fixed['L']:.3g} H: samples {dt_med:.3g} s apart cannot show "
        "the electrical time constant"
    )


def _baseline(search: _Search) -> _Fitted:
    """The linear model fitted on the fit segments and scored on the held-out ones."""
    cfg, split, noise = search.cfg, search.split, search.noise
    p0 = cfg.initial or equation_error_start(split.fit, search.fixed)
    try:
        base = search.evaluate((), Model(p0))
    except _FIT_ERRORS as exc:
        msg = f"the baseline linear model could not be fitted to these data ({exc})"
        raise DataError(msg) from None
    if cfg.initial is None and "L" not in search.fixed:
        # When L/R is below the sample period the engine holds L at its start value,
        # so place that start by simulation on the fit segments and refit.
        p_l = _scan_inductance(base.fit.model.params, split.fit, noise, cfg.fixed)
        if p_l.L != base.fit.model.params.L:
            try:
                again = search.evaluate((), Model(p_l))
            except _FIT_ERRORS:
                again = base
            if _fit_gap(again, split.fit, noise) < _fit_gap(base, split.fit, noise):
                base = again
    if "L" not in search.fixed and not base.fit.identifiable.get("L", True):
        # L/R below the sample period: hold L for the candidates (one fit, not two)
        search.fixed["L"] = float(base.fit.model.params.L)
    search.say(f"baseline (linear model): held-out gap {base.gap:.3g}")
    return base


def _scan_inductance(
    p: MotorParams, segments: Sequence[Segment], noise: NoiseModel, fixed: Mapping[str, float]
) -> MotorParams:
    """Place L by simulation: the output-error fit holds L at its start when the data
    cannot resolve L/R, so the start must already match the first samples of steps."""
    if "L" in fixed:
        return p
    dt = float(np.median([s.dt_s for s in segments]))

    def gap_at(log_k: float) -> float:
        trial = p.replace(L=p.R * dt * math.exp(log_k))
        return residuals(segments, predict(Model(trial), segments), noise).gap()

    grid = np.log([0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0])
    gaps = [gap_at(x) for x in grid]
    k = int(np.argmin(gaps))
    lo, hi = grid[max(k - 1, 0)], grid[min(k + 1, grid.size - 1)]
    golden = (math.sqrt(5.0) - 1.0) / 2.0
    a, b = hi - golden * (hi - lo), lo + golden * (hi - lo)
    ga, gb = gap_at(a), gap_at(b)
    for _ in range(8):  # golden-section refinement in log(L)
        if ga < gb:
            hi, b, gb = b, a, ga
            a = hi - golden * (hi - lo)
            ga = gap_at(a)
        else:
            lo, a, ga = a, b, gb
            b = lo + golden * (hi - lo)
            gb = gap_at(b)
    best_x = min([(gaps[k], grid[k]), (ga, a), (gb, b)])[1]
    return p.replace(L=p.R * dt * math.exp(best_x))


def _fit_gap(f: _Fitted, segments: Sequence[Segment], noise: NoiseModel) -> float:
    return residuals(segments, _predictions(f.fit, segments), noise).gap()


def _predictions(fit: FitResult, segments: Sequence[Segment]) -> list[Prediction]:
    return list(fit.simulate_segments(list(segments)))


def _estimates(fit: FitResult, user_fixed: Mapping[str, float]) -> tuple[ParameterEstimate, ...]:
    """The fit's estimates; a value the diagnosis held (not the user) says so."""
    out = []
    for name in fit.values:
        est = estimate_from_fit(fit, name, "output_error")
        if name in fit.fixed and name not in user_fixed:
            est = replace(est, reason="held by the diagnosis (see the assumptions)", method="held")
        out.append(est)
    return tuple(out)


@dataclass
class _Fitted:
    effects: tuple[str, ...]
    fit: FitResult
    res: Residuals
    gap: float
    seconds: float
    failed: bool = False


class _Search:
    """Fits candidates on the fit segments and scores them on the held-out ones."""

    def __init__(
        self,
        split: HoldoutSplit,
        noise: NoiseModel,
        cfg: DiagnosisConfig,
        progress: ProgressCallback | None,
    ) -> None:
        self.split = split
        self.noise = noise
        self.cfg = cfg
        self.progress = progress
        self.fixed = dict(cfg.fixed)

    def say(self, text: str) -> None:
        if self.progress is not None:
            self.progress(text)

    def evaluate(self, effects: tuple[str, ...], model: Model) -> _Fitted:
        t0 = time.perf_counter()
        fixed = dict(self.fixed)
        if "L" in fixed and "L" not in self.cfg.fixed:
            fixed["L"] = float(model.params.L)  # held where the candidate's scan put it
        fit = fit_model(self.split.fit, model, max_nfev=self.cfg.max_nfev, fixed=fixed or None)
        res = residuals(self.split.held_out, _predictions(fit, self.split.held_out), self.noise)
        return _Fitted(effects, fit, res, res.gap(), time.perf_counter() - t0)

    def try_evaluate(self, effects: tuple[str, ...], model: Model, fallback: _Fitted) -> _Fitted:
        """Like :meth:`evaluate`, but a fit that fails numerically scores as no better
        than ``fallback`` (the candidate is then simply not chosen)."""
        try:
            return self.evaluate(effects, model)
        except _FIT_ERRORS as exc:
            self.say(f"candidate {'+'.join(effects)}: fit failed ({exc})")
            return _Fitted(effects, fallback.fit, fallback.res, fallback.gap, 0.0, failed=True)

    def single(self, base: _Fitted, name: str, sc: DataScales) -> _Fitted:
        start = scan_start(base.fit.model, name, sc, self.split.fit, self.noise)
        out = self.try_evaluate((name,), start, base)
        self.say(f"candidate {name}: held-out gap {out.gap:.3g} ({out.seconds:.1f} s)")
        return out


def _n_added(model: Model, names: Sequence[str]) -> int:
    return sum(len(e.fitted_names()) for e in model.effects if e.NAME in names)


# ---------------------------------------------------------------------------
# 3.-4. candidates, scored against the baseline
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _Scoring:
    """Scores candidates against the baseline's held-out gap ``g0``: each added
    parameter costs ``penalty`` (gap units)."""

    g0: float
    penalty: float
    noise_rel: float
    thresholds: Thresholds

    @classmethod
    def for_baseline(cls, base: _Fitted, noise: NoiseModel, th: Thresholds) -> _Scoring:
        g0 = base.gap
        noise_rel = float(np.mean([noise.noise_rel(s) for s in noise.signals]))
        penalty = max(
            th.penalty_rel_per_param * max(g0, 0.0), th.penalty_noise_per_param * noise_rel
        )
        return cls(g0, penalty, noise_rel, th)

    def score(self, f: _Fitted, parent: _Fitted | None = None) -> CandidateScore:
        g0, penalty = self.g0, self.penalty
        k = _n_added(f.fit.model, f.effects)
        gain = g0 - f.gap
        # a combination must beat its parent by the penalty of what it adds
        k_new = k if parent is None else k - _n_added(parent.fit.model, parent.effects)
        gain_new = gain if parent is None else parent.gap - f.gap
        eff_params = {
            f"{e.NAME}.{fld}": float(v)
            for e in f.fit.model.effects
            for fld, v in e.as_dict().items()
        }
        return CandidateScore(
            effects=f.effects,
            gap=f.gap,
            shrink=(gain / g0) if g0 > 0 else 0.0,
            added_parameters=k,
            penalized_gap=f.gap + k * penalty,
            significant=bool(gain_new > k_new * penalty and not f.failed),
            parameters=eff_params,
            fit_seconds=f.seconds,
        )


def _single_candidates(
    search: _Search, base: _Fitted, loc: Localization
) -> tuple[dict[str, str], list[_Fitted]]:
    """Every testable effect fitted alone; also what could not be tried, and why.

    Cogging is tried when the residuals are periodic in the shaft angle (it is the
    costliest fit, and the output error of a rotor caught in detents is multimodal).
    """
    cfg = search.cfg
    periods = list(loc.angle_candidates) if loc.angle_periods_per_rev else []
    sc = data_scales(search.split.fit, base.fit.model.params.Kt, periods)
    untestable: dict[str, str] = {}
    if not periods:
        untestable["cogging"] = "no periodicity in shaft angle in the residuals"
    if "L" in search.fixed:
        untestable["inductance_saturation"] = "L is held (the data do not resolve L/R)"
    names = [n for n in cfg.effects if n not in untestable]
    with ThreadPoolExecutor(max_workers=cfg.workers) as pool:
        singles = list(pool.map(lambda n: search.single(base, n, sc), names))
    return untestable, singles


# ---------------------------------------------------------------------------
# 5. the choice
# ---------------------------------------------------------------------------
@dataclass
class _Choice:
    """The chosen candidate (the baseline when none helps), ties and every score."""

    chosen: _Fitted
    gap_significant: bool
    ties: list[Tie] = field(default_factory=list)
    scores: list[CandidateScore] = field(default_factory=list)


def _choose(search: _Search, scoring: _Scoring, base: _Fitted, singles: list[_Fitted]) -> _Choice:
    th, g0 = scoring.thresholds, scoring.g0
    scored = sorted(((scoring.score(f), f) for f in singles), key=lambda sf: sf[0].penalized_gap)
    helping = [(s, f) for s, f in scored if s.significant]
    # A gap below the noise level still counts when an effect, fitted without the
    # held-out samples, beats its penalty on them and closes most of that gap: the
    # held-out improvement is the evidence (on effect-free runs no candidate does).
    shown = bool(helping) and g0 > 0 and (g0 - helping[0][0].gap) >= th.explained_shrink * g0
    gap_significant = g0 > th.no_gap_noise * scoring.noise_rel or shown
    choice = _Choice(base, gap_significant, scores=[s for s, _ in scored])
    if not (helping and gap_significant):
        return choice
    best_s, best_f = _break_ties(helping, g0, th, choice.ties)
    choice.chosen = best_f
    tied_names = {n for t in choice.ties for n in t.effects}
    by_name = {f.effects[0]: f for f in singles}
    ranked_names = [
        s.effects[0]
        for s, _ in scored
        if s.effects[0] not in tied_names and not by_name[s.effects[0]].failed
    ]
    _combine(search, scoring, choice, by_name, ranked_names)
    return choice


def _break_ties(
    helping: list[tuple[CandidateScore, _Fitted]],
    g0: float,
    th: Thresholds,
    ties: list[Tie],
) -> tuple[CandidateScore, _Fitted]:
    """The best helping candidate; candidates that close nearly as much of the gap with
    as many parameters are ties, ordered by :func:`order_tie` and named in ``ties``."""
    best_s, best_f = helping[0]
    gain_best = g0 - best_s.gap
    tied = [
        (s, f)
        for s, f in helping[1:]
        if (g0 - s.gap) >= (1.0 - th.tie_fraction) * gain_best
        and s.added_parameters == best_s.added_parameters
    ]
    if tied:
        group = order_tie([best_s.effects[0]] + [s.effects[0] for s, _ in tied])
        lookup = {s.effects[0]: (s, f) for s, f in [(best_s, best_f), *tied]}
        best_s, best_f = lookup[group[0]]
        for other in group[1:]:
            ties.append(Tie((group[0], other), separating_test(group[0], other)))
    return best_s, best_f


def _combine(
    search: _Search,
    scoring: _Scoring,
    choice: _Choice,
    by_name: Mapping[str, _Fitted],
    ranked_names: Sequence[str],
) -> None:
    """Greedy forward selection while most of the gap remains: add the effect that
    lowers the penalized gap most, while it beats the penalty of what it adds."""
    g0, penalty = scoring.g0, scoring.penalty
    th = scoring.thresholds
    while (
        len(choice.chosen.effects) < search.cfg.max_effects
        and g0 > 0
        and (g0 - choice.chosen.gap) / g0 < th.combine_below_shrink
    ):
        chosen = choice.chosen
        pool_names = [n for n in ranked_names if n not in chosen.effects][:4]
        if not pool_names:
            break

        def combo(n: str, base_fit: _Fitted = chosen) -> _Fitted:
            e = by_name[n].fit.model.effect(n)
            assert e is not None
            m = base_fit.fit.model.with_effects(e)
            out = search.try_evaluate((*base_fit.effects, n), m, base_fit)
            search.say(f"combination {'+'.join(out.effects)}: held-out gap {out.gap:.3g}")
            return out

        with ThreadPoolExecutor(max_workers=search.cfg.workers) as pool:
            trials = list(pool.map(combo, pool_names))
        best_trial = min(trials, key=lambda f: f.gap + _n_added(f.fit.model, f.effects) * penalty)
        choice.scores.extend(scoring.score(f, chosen) for f in trials)
        k_new = _n_added(best_trial.fit.model, best_trial.effects[-1:])
        if chosen.gap - best_trial.gap > k_new * penalty:
            choice.chosen = best_trial
        else:
            break


# ---------------------------------------------------------------------------
# 6. verdict, regimes, assumptions
# ---------------------------------------------------------------------------
def _verdict(choice: _Choice, scoring: _Scoring) -> Verdict:
    g0, noise_rel, chosen = scoring.g0, scoring.noise_rel, choice.chosen
    shrink = (g0 - chosen.gap) / g0 if g0 > 0 else 0.0
    if not chosen.effects:
        if choice.gap_significant and g0 > 0:
            status = VerdictStatus.UNEXPLAINED
            message = (
                f"the linear model leaves a held-out gap of {g0:.3g} (noise {noise_rel:.2g}) "
                "and no candidate effect closes it beyond its penalty"
            )
        else:
            status = VerdictStatus.NO_GAP
            message = (
                f"the linear model matches held-out data to the noise (gap {g0:.3g}, "
                f"noise {noise_rel:.2g}); no effect is needed"
            )
    elif shrink >= scoring.thresholds.explained_shrink:
        status = VerdictStatus.EXPLAINED
        message = (
            f"{' + '.join(chosen.effects)} closes {shrink:.0%} of the held-out gap "
            f"({g0:.3g} -> {chosen.gap:.3g})"
        )
    else:
        status = VerdictStatus.UNEXPLAINED
        message = (
            f"best candidate {' + '.join(chosen.effects)} closes only {shrink:.0%} of the "
            "held-out gap; the rest has no name in the vocabulary"
        )
    if status is not VerdictStatus.EXPLAINED:
        return Verdict(status, (), (), message)
    return Verdict(status, chosen.effects, tuple(choice.ties), message)


def _regimes(
    masks: Mapping[str, Mapping[str, np.ndarray]], base: _Fitted, final: _Fitted
) -> tuple[RegimeShrink, ...]:
    return tuple(
        RegimeShrink(cat, lab, float(mk.mean()), base.res.gap(mk), final.res.gap(mk))
        for cat, groups in masks.items()
        for lab, mk in groups.items()
        if mk.any()
    )


def _assumptions(
    search: _Search, slow_note: str, penalty: float, untestable: Mapping[str, str]
) -> tuple[str, ...]:
    cfg = search.cfg
    out = ["closure Kt = Ke (SI units)"]
    if slow_note:
        out.append(slow_note)
    elif "L" in search.fixed and "L" not in cfg.fixed:
        out.append(
            f"L held at {search.fixed['L']:.3g} H: L/R is below the sample period, so the "
            "data cannot resolve it"
        )
    if cfg.fixed:
        out.append("held fixed: " + ", ".join(f"{k} = {v:g}" for k, v in cfg.fixed.items()))
    out.append(f"penalty per added parameter: {penalty:.3g} (gap units)")
    for n, why in untestable.items():
        if n in cfg.effects:
            out.append(f"{n} not tried: {why}")
    return tuple(out)
