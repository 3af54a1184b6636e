"""Candidate fits and their scores: the fit set, the held-out set, the penalty.

A :class:`Search` fits a model on the diagnosis' fit segments and measures its
held-out gap; :class:`Scoring` turns a fit into a :class:`CandidateScore` against
the baseline, each added parameter costing ``penalty`` (gap units).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis.candidates import DataScales, fit_model, free_fields, scan_start
from pmdc_ident.core.diagnosis.config import DiagnosisConfig
from pmdc_ident.core.diagnosis.holdout import HoldoutSplit
from pmdc_ident.core.diagnosis.leadin import LeadIn, lead_ins, predict_held_out
from pmdc_ident.core.diagnosis.results import CandidateScore
from pmdc_ident.core.diagnosis.scoring import NoiseModel, Residuals, residuals
from pmdc_ident.core.diagnosis.verdict import Thresholds
from pmdc_ident.core.effects import Effect
from pmdc_ident.core.estimators.output_error import FitResult, Prediction
from pmdc_ident.core.model import Model
from pmdc_ident.core.progress import ProgressCallback

__all__ = ["FIT_ERRORS", "L_FLOOR_SAMPLE", "Fitted", "Scoring", "Search", "n_added", "predictions"]

FIT_ERRORS = (ValueError, ArithmeticError, np.linalg.LinAlgError)
# the smallest L/R a fit starts from or holds, as a fraction of the sample period
L_FLOOR_SAMPLE = 0.01


def predictions(fit: FitResult, segments: Sequence[Segment]) -> list[Prediction]:
    return list(fit.simulate_segments(list(segments)))


@dataclass
class Fitted:
    effects: tuple[str, ...]
    fit: FitResult
    res: Residuals
    gap: float
    seconds: float
    failed: bool = False


class Search:
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
        self.leads = [LeadIn(seg, 0) for seg in split.held_out]
        # the records' sample period (the scale of the signal chain's lag)
        self.dt_s = float(np.median([s.dt_s for s in (*split.fit, *split.held_out)]))
        # what the result must say about a candidate that was fitted but cannot be named
        # (a cogging whose period the sampling does not resolve, ...)
        self.notes: list[str] = []

    def set_lead_ins(self, tau_s: float) -> None:
        """Predict held-out segments from lead-ins of ``LEAD_IN_TAU`` x ``tau_s``."""
        self.leads = lead_ins([*self.split.fit, *self.split.held_out], self.split.held_out, tau_s)

    def held_out_predictions(self, fit: FitResult) -> list[Prediction]:
        return predict_held_out(fit, self.leads)

    def held_out_residuals(self, fit: FitResult) -> Residuals:
        return residuals(self.split.held_out, self.held_out_predictions(fit), self.noise)

    def say(self, text: str) -> None:
        if self.progress is not None:
            self.progress(text)

    def evaluate(self, effects: tuple[str, ...], model: Model) -> Fitted:
        t0 = time.perf_counter()
        model = self.resolvable(model)
        fixed = dict(self.fixed)
        if "L" in fixed and "L" not in self.cfg.fixed:
            fixed["L"] = float(model.params.L)  # held where the candidate's scan put it
        fit = fit_model(self.split.fit, model, max_nfev=self.cfg.max_nfev, fixed=fixed or None)
        res = self.held_out_residuals(fit)
        return Fitted(effects, fit, res, res.gap(), time.perf_counter() - t0)

    def resolvable(self, model: Model) -> Model:
        """``model`` with L/R at least :data:`L_FLOOR_SAMPLE` of a sample: the current
        settles within the sample either way, so the data cannot tell a smaller L, and
        an L run towards 0 (exp(-R dt / L) at 1e-6 of a sample) leaves a friction
        candidate's first step undifferentiable ("the fit cannot start")."""
        p = model.params
        floor = L_FLOOR_SAMPLE * p.R * self.dt_s
        if "L" in self.cfg.fixed or p.L >= floor:
            return model
        return Model(p.replace(L=floor), model.effects)

    def try_evaluate(self, effects: tuple[str, ...], model: Model, fallback: Fitted) -> Fitted:
        """Like :meth:`evaluate`, but a fit that fails numerically scores as no better
        than ``fallback`` (the candidate is then simply not chosen)."""
        try:
            return self.evaluate(effects, model)
        except FIT_ERRORS as exc:
            self.say(f"candidate {'+'.join(effects)}: fit failed ({exc})")
            return Fitted(effects, fallback.fit, fallback.res, fallback.gap, 0.0, failed=True)

    def scan(
        self, base: Fitted, name: str, sc: DataScales, keep: Callable[[Effect], bool] | None = None
    ) -> tuple[Model, float]:
        """The best start for a candidate and its gap on the fit segments."""
        return scan_start(base.fit.model, name, sc, self.split.fit, self.noise, keep)

    def single(
        self,
        base: Fitted,
        name: str,
        sc: DataScales,
        keep: Callable[[Effect], bool] | None = None,
        start: Model | None = None,
    ) -> Fitted:
        if start is None:
            start, _ = self.scan(base, name, sc, keep)
        out = self.try_evaluate((name,), start, base)
        self.say(f"candidate {name}: held-out gap {out.gap:.3g} ({out.seconds:.1f} s)")
        return out


def n_added(model: Model, names: Sequence[str]) -> int:
    return sum(len(free_fields(e)) for e in model.effects if e.NAME in names)


@dataclass(frozen=True)
class Scoring:
    """Scores candidates against the baseline's held-out gap ``g0``: each added
    parameter costs ``penalty`` (gap units)."""

    g0: float
    penalty: float
    thresholds: Thresholds

    @classmethod
    def for_baseline(cls, base: Fitted, th: Thresholds) -> Scoring:
        g0 = base.gap  # in noise variances (see core.diagnosis.scoring)
        penalty = max(th.penalty_rel_per_param * max(g0, 0.0), th.penalty_noise_per_param)
        return cls(g0, penalty, th)

    def closes_most(self, gap: float) -> bool:
        """Whether a model that leaves ``gap`` closes most of the baseline's gap
        (``explained_shrink`` of it)."""
        return self.g0 - gap >= self.thresholds.explained_shrink * self.g0

    def closes(self, gap: float) -> bool:
        """Whether a model that leaves ``gap`` closes the baseline's gap as an explained
        verdict requires: most of it, or down to the noise (``no_gap_noise``)."""
        return self.closes_most(gap) or gap <= self.thresholds.no_gap_noise

    def penalized(self, f: Fitted) -> float:
        """``f``'s held-out gap plus ``penalty`` per parameter it adds (infinite for a
        fit that failed): the figure candidates are compared by."""
        return math.inf if f.failed else f.gap + n_added(f.fit.model, f.effects) * self.penalty

    def score(self, f: Fitted, parent: Fitted | None = None) -> CandidateScore:
        g0, penalty = self.g0, self.penalty
        k = n_added(f.fit.model, f.effects)
        gain = g0 - f.gap
        # a combination must beat its parent by the penalty of what it adds
        k_new = k if parent is None else k - n_added(parent.fit.model, parent.effects)
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
            penalized_gap=f.gap + k * penalty,  # as penalized(), reported for a failed fit
            significant=bool(gain_new > k_new * penalty and not f.failed),
            parameters=eff_params,
            fit_seconds=f.seconds,
        )
