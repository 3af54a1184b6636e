"""Scores a reviewer can check: accuracy, ties, false attribution, limits.

Definitions (one run = one diagnosed file):

* **top-1**: the first named effect is the truth.
* **tie-honest**: top-1, or the truth is tied with the first named effect and the
  tie names the test that separates them.
* **visible**: the generated effect changes the noise-free logged current or speed
  by at least one noise standard deviation (RMS over the run, computed by the
  generator from a twin run without the effect). Below that, ``no_gap`` is the
  honest answer; such runs are counted apart and still enter the detection limits.
* **false attribution**: an effect-free run with any effect named.
* **unexplained rate**: out-of-vocabulary runs whose verdict is ``unexplained``,
  over the visible ones (the same rule as effect runs: an out-of-vocabulary effect
  the noise hides leaves the linear model nothing to miss, and ``no_gap`` is then the
  honest answer); the rate over all of them is reported beside it.
* **detection limit** of an effect: the smallest ladder size from which on every
  size is named tie-honestly in at least 90 % of its runs (all runs of that size).
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pmdc_ident.benchmark.runner import Outcome
from pmdc_ident.benchmark.truth import LADDERS, VOCABULARY

__all__ = ["VISIBLE", "Score", "right_tie_honest", "right_top1", "score"]

VISIBLE = 1.0  # effect RMS over noise RMS
LIMIT_RATE = 0.9


def right_top1(o: Outcome) -> bool:
    return bool(o.effects) and o.effects[0] == o.case.truth[0]


def tied_with_truth(o: Outcome, truth: str) -> bool:
    """The truth is tied with a named effect, and the tie names its separating test."""
    return any(
        truth in names and any(n in names for n in o.effects) and bool(test.strip())
        for names, test in o.ties
    )


def right_tie_honest(o: Outcome) -> bool:
    return right_top1(o) or (bool(o.effects) and tied_with_truth(o, o.case.truth[0]))


def compound_right(o: Outcome) -> bool:
    """Every true effect named, or tied (with its test) with a named one."""
    return all(t in o.effects or tied_with_truth(o, t) for t in o.case.truth)


def _rate(xs: Sequence[bool]) -> float:
    return sum(xs) / len(xs) if xs else math.nan


@dataclass(frozen=True)
class Limit:
    name: str
    unit: str
    by_level: tuple[tuple[float, int, int], ...]  # (size, right, runs)
    limit: float | None  # smallest size from which on >= 90 %; None = not reached

    def text(self) -> str:
        if self.limit is None:
            top = self.by_level[-1][0] if self.by_level else math.nan
            return f"> {top:g} {self.unit}"
        return f"{self.limit:g} {self.unit}"


@dataclass(frozen=True)
class Score:
    outcomes: tuple[Outcome, ...]

    def of_kind(self, kind: str) -> list[Outcome]:
        return [o for o in self.outcomes if o.case.kind == kind]

    @property
    def effect_runs(self) -> list[Outcome]:
        return self.of_kind("effect")

    @property
    def visible(self) -> list[Outcome]:
        return [o for o in self.effect_runs if not (o.case.visibility < VISIBLE)]

    @property
    def hidden(self) -> list[Outcome]:
        return [o for o in self.effect_runs if o.case.visibility < VISIBLE]

    def top1(self, runs: Sequence[Outcome] | None = None) -> float:
        return _rate([right_top1(o) for o in (self.visible if runs is None else runs)])

    def tie_honest(self, runs: Sequence[Outcome] | None = None) -> float:
        return _rate([right_tie_honest(o) for o in (self.visible if runs is None else runs)])

    @property
    def false_attribution(self) -> tuple[int, int]:
        clean = self.of_kind("clean")
        return sum(1 for o in clean if o.effects), len(clean)

    @property
    def oov_verdicts(self) -> Counter[str]:
        """Verdicts of every out-of-vocabulary run, visible or not."""
        return Counter(o.status for o in self.of_kind("oov"))

    @property
    def oov_visible(self) -> list[Outcome]:
        """Out-of-vocabulary runs whose effect the noise does not hide (unmeasured:
        visible, as for effect runs)."""
        return [o for o in self.of_kind("oov") if not (o.case.visibility < VISIBLE)]

    @property
    def oov_unexplained(self) -> tuple[int, int]:
        """(``unexplained``, runs) over the visible out-of-vocabulary runs."""
        vis = self.oov_visible
        return sum(1 for o in vis if o.status == "unexplained"), len(vis)

    @property
    def median_shrink_right(self) -> float:
        s = [o.shrink for o in self.visible if right_tie_honest(o) and math.isfinite(o.shrink)]
        return float(np.median(s)) if s else math.nan

    def per_effect(self) -> dict[str, tuple[int, int, int, int]]:
        """name -> (top-1 right, tie-honest right, visible runs, hidden runs)."""
        out = {}
        for n in VOCABULARY:
            vis = [o for o in self.visible if o.case.truth[0] == n]
            hid = [o for o in self.hidden if o.case.truth[0] == n]
            if vis or hid:
                out[n] = (
                    sum(map(right_top1, vis)),
                    sum(map(right_tie_honest, vis)),
                    len(vis),
                    len(hid),
                )
        return out

    def per_equation(self) -> dict[tuple[str, str], tuple[int, int]]:
        acc: dict[tuple[str, str], list[bool]] = defaultdict(list)
        for o in self.visible:
            e = o.case.effects[0]
            acc[(e.name, e.equation)].append(right_tie_honest(o))
        return {k: (sum(v), len(v)) for k, v in sorted(acc.items())}

    def limits(self) -> list[Limit]:
        out = []
        for n in VOCABULARY:
            unit, sizes = LADDERS[n]
            runs = [o for o in self.effect_runs if o.case.truth[0] == n]
            if not runs:
                continue
            rows = []
            for lev, size in enumerate(sizes):
                at = [o for o in runs if o.case.effects[0].level == lev]
                rows.append((size, sum(map(right_tie_honest, at)), len(at)))
            limit = None
            for k in range(len(rows)):
                tail = [r for r in rows[k:] if r[2]]
                if tail and all(ok >= LIMIT_RATE * m for _, ok, m in tail) and rows[k][2]:
                    limit = rows[k][0]
                    break
            out.append(Limit(n, unit, tuple(rows), limit))
        return out

    def confusion(self) -> dict[str, Counter[str]]:
        """truth -> named (top-1); effect rows over visible runs; ``tie`` counts runs
        whose truth was tied (with its test) with the first named effect."""
        rows: dict[str, Counter[str]] = {}
        for o in self.visible:
            row = rows.setdefault(o.case.truth[0], Counter())
            row[o.top1] += 1
            if not right_top1(o) and right_tie_honest(o):
                row["(tie)"] += 1
        for kind, label in (("clean", "none"), ("oov", "out-of-vocabulary")):
            for o in self.of_kind(kind):
                rows.setdefault(label, Counter())[o.top1] += 1
        return rows

    @property
    def compounds(self) -> tuple[int, int, int]:
        runs = self.of_kind("compound")
        one = sum(1 for o in runs if o.effects and o.effects[0] in o.case.truth)
        return sum(map(compound_right, runs)), one, len(runs)

    @property
    def seconds(self) -> list[float]:
        return [o.seconds for o in self.outcomes if o.seconds > 0]


def score(outcomes: Sequence[Outcome]) -> Score:
    return Score(tuple(outcomes))
