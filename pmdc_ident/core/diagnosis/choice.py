"""The choice among candidates: the best significant one, honest ties, combinations.

Two candidates are a **tie** when the held-out evidence cannot separate them: the
held-out samples are cut into contiguous blocks, and the second candidate is tied
with the best one unless its excess error (plus the penalty of any extra parameter)
is larger by at least two standard errors of the block means, or the two close the
gap within ``tie_fraction`` of each other. A tie is reported with the test that
would separate the two (:func:`~pmdc_ident.core.diagnosis.verdict.separating_test`).

**Combinations** are tried whenever an effect is named, not only when much of the
gap remains: an effect is added to the chosen model when that beats the chosen
model on held-out data by the penalty of what it adds (greedy, up to
``max_effects``).

**The signal chain's lag** (a delay shorter than a first-order anti-alias filter's lag
at the Nyquist frequency, 1/pi sample: :func:`chain_lag_s`) is in every driver's
record, so it is no effect: when it is the best single candidate, every other helping
effect is tried on top of it and judged against it as a single effect is judged
against the baseline (its penalty, ties); when an effect is chosen that leaves most of
the gap, the lag is tried on top of it the same way (:func:`with_chain_lag`); the lag
itself is never named.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from pmdc_ident.core.diagnosis.results import CandidateScore, Tie
from pmdc_ident.core.diagnosis.search import Fitted, Scoring, Search, n_added
from pmdc_ident.core.diagnosis.verdict import order_tie, separating_test
from pmdc_ident.core.model import Model

__all__ = ["Choice", "chain_lag_s", "choose"]


@dataclass
class Choice:
    """The chosen candidate (the baseline when none helps), ties and every score."""

    chosen: Fitted
    gap_significant: bool
    ties: list[Tie] = field(default_factory=list)
    scores: list[CandidateScore] = field(default_factory=list)


TIE_BLOCKS = 20  # contiguous blocks of held-out samples for the evidence test
TIE_SIGMAS = 2.0  # a difference of fewer standard errors than this separates nothing


def choose(search: Search, scoring: Scoring, base: Fitted, singles: list[Fitted]) -> Choice:
    th, g0 = scoring.thresholds, scoring.g0
    scored = sorted(((scoring.score(f), f) for f in singles), key=lambda sf: sf[0].penalized_gap)
    helping = [(s, f) for s, f in scored if s.significant]
    # A gap below the noise level still counts when an effect, fitted without the
    # held-out samples, beats its penalty on them and closes most of that gap: the
    # held-out improvement is the evidence (on effect-free runs no candidate does).
    shown = bool(helping) and g0 > 0 and scoring.closes_most(helping[0][0].gap)
    gap_significant = g0 > th.no_gap_noise or shown
    choice = Choice(base, gap_significant, scores=[s for s, _ in scored])
    if not (helping and gap_significant):
        return choice
    choice.chosen = break_ties(helping, scoring, choice.ties)
    by_name = {f.effects[0]: f for f in singles}
    ranked_names = [s.effects[0] for s, f in helping if not f.failed]
    if chain_lag_s(choice.chosen, search.dt_s) is not None:
        beyond_chain_lag(search, scoring, choice, by_name, ranked_names)
    else:
        with_chain_lag(search, scoring, choice, by_name)
    combine(search, scoring, choice, by_name, ranked_names)
    return choice


def chain_lag_s(f: Fitted, dt_s: float) -> float | None:
    """The delay in ``f``'s effects when it is shorter than the lag of a first-order
    anti-alias filter at the Nyquist frequency (1/pi sample): every driver's signal
    chain lags that much (the filter, the ADC's conversion instant), so it is no
    effect of the motor or the drive."""
    if "delay" not in f.effects:
        return None
    e = f.fit.model.effect("delay")
    # a first-order lag delays slow signals by its time constant
    lag = float(getattr(e, "delay_s", math.inf)) + float(getattr(e, "lag_s", 0.0))
    return lag if lag < dt_s / math.pi else None


def beyond_chain_lag(
    search: Search,
    scoring: Scoring,
    choice: Choice,
    by_name: Mapping[str, Fitted],
    ranked_names: Sequence[str],
) -> None:
    """The chosen candidate is the signal chain's lag: every other helping effect is
    fitted with it and scored against it as a single effect against the baseline (its
    penalty, ties); the best that helps is chosen with the lag, which stays unnamed."""
    lag = choice.chosen
    names = [n for n in ranked_names if n not in lag.effects][:4]
    trials = [t for t in _with_each(search, lag, by_name, names) if not t.failed]
    scored = sorted(
        ((scoring.score(t, lag), t) for t in trials), key=lambda sf: sf[0].penalized_gap
    )
    choice.scores.extend(s for s, _ in scored)
    helping = [(s, t) for s, t in scored if s.significant]
    if helping:
        choice.ties.clear()
        choice.chosen = break_ties(helping, scoring, choice.ties)


def with_chain_lag(
    search: Search, scoring: Scoring, choice: Choice, by_name: Mapping[str, Fitted]
) -> None:
    """The chosen effect leaves most of the gap and the delay did not help alone, or
    helped only as a chain lag (a Coulomb friction whose current steps the sensor's
    filter rounds off: the lag closes a little of the gap alone, the friction the
    rest, and combined as an effect the lag would be judged as a delay): the
    signal chain's lag is tried on top of it, judged against it as a single effect
    against the baseline (its penalty), and kept only where its delay stays a chain lag
    (:func:`chain_lag_s`, so it names nothing) and the effect still beats its penalty
    over the lag refitted alone (a lag that closes the gap by itself needs no effect).
    The linear model's L absorbs much of a chain lag (alone it barely helps), a model
    whose current response is otherwise bound no longer can: an inductance that
    saturates leaves the lag of the current sensor's filter in its high-frequency
    residuals."""
    chosen, lag = choice.chosen, by_name.get("delay")
    if (
        lag is None
        or lag.failed
        or "delay" in chosen.effects
        # a delay that helps alone is combined as an effect, unless it is itself only
        # a chain lag (its helping alone is the filter's lag, not a dead time)
        or (scoring.score(lag).significant and chain_lag_s(lag, search.dt_s) is None)
        or scoring.closes_most(chosen.gap)
    ):
        return
    (trial,) = _with_each(search, chosen, by_name, ["delay"])
    if trial.failed or chain_lag_s(trial, search.dt_s) is None:
        return
    s = scoring.score(trial, chosen)
    choice.scores.append(s)
    if not s.significant:
        return
    # the effect must earn its place on top of the lag too: the lag refitted alone from
    # where the trial put it (its own single fit may have stopped short of it), judged
    # as the effect on top of the lag would be against the baseline
    delay = trial.fit.model.effect("delay")
    assert delay is not None
    alone = search.try_evaluate(("delay",), Model(trial.fit.model.params, (delay,)), trial)
    if alone.failed:
        return
    if scoring.score(trial, alone).significant:
        choice.chosen = trial
    elif chain_lag_s(alone, search.dt_s) is not None and alone.gap < chosen.gap:
        # the lag alone does what the effect did on top of it: the chosen effect only
        # stood in for the lag (the delay's own single fit stopped in another optimum,
        # a lag of a sample or more that L offsets on the fitted quarters of a sweep
        # and not on the held-out faster ones). No effect is needed: the chain's lag
        # is chosen alone (the verdict weighs what it leaves as the baseline's gap),
        # never the effect that closed a few per cent of the gap (an effect-free
        # servo at 1 kHz behind a 5 kHz two-pole current filter ended 'unexplained')
        choice.ties.clear()
        choice.chosen = alone


def _with_each(
    search: Search, chosen: Fitted, by_name: Mapping[str, Fitted], names: Sequence[str]
) -> list[Fitted]:
    """``chosen`` with each named effect added (as fitted alone), refitted together."""

    def combo(n: str) -> Fitted:
        e = by_name[n].fit.model.effect(n)
        assert e is not None
        m = chosen.fit.model.with_effects(e)
        out = search.try_evaluate((*chosen.effects, n), m, chosen)
        search.say(f"combination {'+'.join(out.effects)}: held-out gap {out.gap:.3g}")
        return out

    with ThreadPoolExecutor(max_workers=search.cfg.workers) as pool:
        return list(pool.map(combo, names))


def separated(
    best: Fitted, other: Fitted, extra_params: int, penalty: float, decisive: float = math.inf
) -> bool:
    """Whether the held-out evidence prefers ``best`` to ``other`` beyond doubt.

    ``extra_params``: parameters ``other`` has beyond ``best`` (negative when fewer),
    each costing ``penalty``. The per-sample excess errors of the two are compared:
    what ``other`` leaves beyond ``best`` (plus the penalty difference) separates them
    when it is itself a gap (``decisive`` noise variances, the no-gap level) or when
    it exceeds :data:`TIE_SIGMAS` standard errors of the means of contiguous blocks.
    The block test alone would tie two effects that differ only where the evidence
    is (a coast-down is one or two blocks of twenty), however large the difference.
    """
    d = other.res.excess_per_sample() - best.res.excess_per_sample()
    if d.size < 2:
        return False
    margin = float(np.mean(d)) + extra_params * penalty
    if margin >= decisive:
        return True
    blocks = [b for b in np.array_split(d, min(TIE_BLOCKS, d.size)) if b.size]
    means = np.array([float(np.mean(b)) for b in blocks])
    se = float(np.std(means, ddof=1)) / np.sqrt(means.size) if means.size > 1 else 0.0
    return margin > TIE_SIGMAS * se


def break_ties(
    helping: list[tuple[CandidateScore, Fitted]], scoring: Scoring, ties: list[Tie]
) -> Fitted:
    """The best helping candidate, and the ties the held-out data leave it.

    Another helping candidate is tied with the best when it too closes most of the
    gap and either closes nearly as much (within ``tie_fraction``) or the held-out
    evidence cannot separate the two (:func:`separated`), whatever their parameter
    counts. The group is ordered by :func:`order_tie`; when that names another member
    than the best, what the evidence cannot separate from the named one joins the
    group too (a Coulomb friction named over a closer Stribeck curve keeps its tie with
    a load torque). Every pair with the first goes into ``ties`` with its separating
    test.
    """
    tied = _tied_with(helping[0], helping[1:], scoring)
    if not tied:
        return helping[0][1]
    # each candidate by the effect it adds (a single's only one; with the chain's lag,
    # the effect tried on top of it)
    members = [helping[0], *tied]
    group = order_tie([s.effects[-1] for s, _ in members])
    lookup = {s.effects[-1]: (s, f) for s, f in helping}
    if group[0] != helping[0][0].effects[-1]:
        rest = [sf for sf in helping if sf[0].effects[-1] not in group]
        more = [s.effects[-1] for s, _ in _tied_with(lookup[group[0]], rest, scoring)]
        group = group[:1] + order_tie(group[1:] + more)
    for other in group[1:]:
        ties.append(Tie((group[0], other), separating_test(group[0], other)))
    return lookup[group[0]][1]


def _tied_with(
    ref: tuple[CandidateScore, Fitted],
    others: Sequence[tuple[CandidateScore, Fitted]],
    scoring: Scoring,
) -> list[tuple[CandidateScore, Fitted]]:
    """The candidates of ``others`` the held-out evidence leaves tied with ``ref``."""
    th, g0, penalty = scoring.thresholds, scoring.g0, scoring.penalty
    ref_s, ref_f = ref
    gain_ref = g0 - ref_s.gap
    return [
        (s, f)
        for s, f in others
        if scoring.closes_most(s.gap)
        and (
            (g0 - s.gap) >= (1.0 - th.tie_fraction) * gain_ref
            or not separated(
                ref_f, f, s.added_parameters - ref_s.added_parameters, penalty, th.no_gap_noise
            )
        )
    ]


def combine(
    search: Search,
    scoring: Scoring,
    choice: Choice,
    by_name: Mapping[str, Fitted],
    ranked_names: Sequence[str],
) -> None:
    """Greedy forward selection: add the helping effect that lowers the penalized gap
    most, while the held-out evidence prefers the larger model beyond the penalty of
    what it adds (:func:`separated`). Tried whatever share of the gap is left, also
    with effects tied with the chosen one (both may be at work).

    One backward step (:func:`_added_alone`): when the effect added to a single one
    does as well alone (the pair does not beat it by the first's penalty beyond
    doubt), the first was only standing in for part of it, and the added effect is
    named alone with the ties the evidence leaves it; at most once per choice."""
    penalty = scoring.penalty
    stepped_back = False
    while len(choice.chosen.effects) < search.cfg.max_effects:
        chosen = choice.chosen
        if chosen.gap <= penalty:
            break  # the gap left is within one parameter's penalty: nothing can pass
        pool_names = [n for n in ranked_names if n not in chosen.effects][:4]
        if not pool_names:
            break

        trials = [t for t in _with_each(search, chosen, by_name, pool_names) if not t.failed]
        if not trials:
            break
        best_trial = min(trials, key=scoring.penalized)
        choice.scores.extend(scoring.score(f, chosen) for f in trials)
        k_new = n_added(best_trial.fit.model, best_trial.effects[-1:])
        # a larger model must be preferred beyond doubt in every block sense (no
        # ``decisive`` shortcut: an added effect must earn its place across the record)
        if chosen.gap - best_trial.gap > k_new * penalty and separated(
            best_trial, chosen, -k_new, penalty
        ):
            alone = None if stepped_back else _added_alone(scoring, chosen, best_trial, by_name)
            if alone is not None:
                stepped_back = True
                _name_alone(scoring, choice, alone, by_name, ranked_names)
                continue
            choice.chosen = best_trial
            named = set(best_trial.effects)
            choice.ties[:] = [t for t in choice.ties if not set(t.effects) <= named]
        else:
            break


def _added_alone(
    scoring: Scoring, chosen: Fitted, pair: Fitted, by_name: Mapping[str, Fitted]
) -> Fitted | None:
    """The effect ``pair`` adds to the single effect ``chosen``, as fitted alone, when
    the pair does not beat it beyond the penalty of ``chosen``'s parameters and beyond
    doubt (:func:`separated`): then ``chosen`` only stood in for part of the added
    effect (a load torque taking the offset of a quadratic drag the staircase shows
    whole), and naming both would attribute a gap to an effect the data do not need."""
    if len(chosen.effects) != 1 or chosen.effects[0] == "delay":
        return None
    alone = by_name.get(pair.effects[-1])
    if alone is None or alone.failed:
        return None
    k_first = n_added(pair.fit.model, chosen.effects)
    penalty = scoring.penalty
    if alone.gap - pair.gap > k_first * penalty and separated(pair, alone, -k_first, penalty):
        return None
    return alone


def _name_alone(
    scoring: Scoring,
    choice: Choice,
    alone: Fitted,
    by_name: Mapping[str, Fitted],
    ranked_names: Sequence[str],
) -> None:
    """Name ``alone`` with the ties the held-out evidence leaves it among the helping
    single effects (each with its separating test)."""
    name = alone.effects[0]
    others = [(scoring.score(by_name[n]), by_name[n]) for n in ranked_names if n != name]
    tied = _tied_with((scoring.score(alone), alone), others, scoring)
    choice.chosen = alone
    choice.ties[:] = [
        Tie((name, s.effects[0]), separating_test(name, s.effects[0])) for s, _ in tied
    ]
