"""Choosing among candidates: penalty, significance, ties and the verdict.

A candidate *helps* when its held-out gap improvement over the baseline beats a
penalty per added parameter. The penalty has two parts: a fraction of the
baseline gap (so a flexible effect cannot win by shaving a little off a large
gap) and a fraction of the measurement-noise variance (so on effect-free data a
lucky fit of noise is not mistaken for an effect); gaps are in noise variances
(:mod:`~pmdc_ident.core.diagnosis.scoring`). Both fractions were
calibrated on effect-free benchmark runs (``pmdc-ident benchmark``) to keep
false attribution at or below 5 %.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from pmdc_ident.core.effects import EFFECT_TYPES

__all__ = [
    "EFFECT_PRIOR",
    "SEPARATING_TESTS",
    "Thresholds",
    "separating_test",
]


@dataclass(frozen=True)
class Thresholds:
    """Decision constants (gaps in noise variances; see module notes)."""

    penalty_rel_per_param: float = 0.02  # of the baseline gap
    penalty_noise_per_param: float = 0.3  # noise variances
    no_gap_noise: float = 1.0  # baseline gap below this many noise variances: no gap
    explained_shrink: float = 0.5  # "most of the gap"
    tie_fraction: float = 0.1  # improvements within 10 % of each other are a tie


# When the data cannot tell effects apart, the one more common in brushed PMDC
# motors is named first (the tie is still reported): each effect's ``PRIOR``.
EFFECT_PRIOR: tuple[str, ...] = tuple(sorted(EFFECT_TYPES, key=lambda n: EFFECT_TYPES[n].PRIOR))

# The test that tells two effects apart, declared by one of the two (its
# ``SEPARATING_TESTS``, keyed by the other's name).
SEPARATING_TESTS: dict[frozenset[str], str] = {
    frozenset({name, other}): text
    for name, cls in EFFECT_TYPES.items()
    for other, text in cls.SEPARATING_TESTS.items()
}


def separating_test(a: str, b: str) -> str:
    key = frozenset({a, b})
    if key in SEPARATING_TESTS:
        return SEPARATING_TESTS[key]
    return (
        f"a test that excites {a} and {b} differently (both directions, low and high "
        "speed, armature open and driven, a longer run)"
    )


def prior_rank(name: str) -> int:
    return EFFECT_PRIOR.index(name) if name in EFFECT_PRIOR else len(EFFECT_PRIOR)


def order_tie(names: Sequence[str]) -> list[str]:
    return sorted(names, key=prior_rank)
