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
# motors is named first (the tie is still reported).
EFFECT_PRIOR: tuple[str, ...] = (
    "coulomb_friction",
    "brush_drop",
    "load_torque",
    "stribeck_friction",
    "quadratic_drag",
    "delay",
    "dead_zone",
    "current_offset",
    "cogging",
    "resistance_drift",
    "inductance_saturation",
)

SEPARATING_TESTS: dict[frozenset[str], str] = {
    frozenset({"coulomb_friction", "load_torque"}): (
        "run the motor in reverse (steps or a staircase with negative voltage): Coulomb "
        "friction changes sign with the direction, a load torque does not"
    ),
    frozenset({"brush_drop", "dead_zone"}): (
        "measure the terminal voltage, or run a low-voltage staircase and a sweep that "
        "reverses current: a dead zone acts on the command, a brush drop on the current"
    ),
    frozenset({"coulomb_friction", "stribeck_friction"}): (
        "run a slow staircase near zero speed: Stribeck friction falls off with speed"
    ),
    frozenset({"coulomb_friction", "brush_drop"}): (
        "compare a coast-down (open armature, no brush drop) with a powered staircase"
    ),
    frozenset({"coulomb_friction", "dead_zone"}): (
        "compare a coast-down (no command) with a powered staircase, or measure the "
        "terminal voltage"
    ),
    frozenset({"coulomb_friction", "current_offset"}): (
        "read the current with the armature open: an offset reads non-zero"
    ),
    frozenset({"load_torque", "current_offset"}): (
        "read the current with the armature open: an offset reads non-zero"
    ),
    frozenset({"quadratic_drag", "coulomb_friction"}): (
        "a staircase up to full speed: quadratic drag grows with speed squared"
    ),
    frozenset({"delay", "inductance_saturation"}): (
        "sample faster (>= 10 samples per L/R) and step at low and high current"
    ),
    frozenset({"resistance_drift", "brush_drop"}): (
        "repeat the staircase at the end of the run: drift makes it differ from the first"
    ),
    frozenset({"stribeck_friction", "load_torque"}): (
        "run in reverse and a slow staircase near zero speed: Stribeck friction changes "
        "sign with the direction and falls off with speed, a load torque does neither"
    ),
    frozenset({"stribeck_friction", "quadratic_drag"}): (
        "a staircase from near zero to full speed: Stribeck friction falls with speed, "
        "drag grows with its square"
    ),
    frozenset({"quadratic_drag", "load_torque"}): (
        "a staircase to full speed in both directions: drag grows with speed squared and "
        "changes sign, a load torque does neither"
    ),
    frozenset({"brush_drop", "load_torque"}): (
        "compare a coast-down (open armature: no brush drop, the load still acts) with a "
        "powered staircase"
    ),
    frozenset({"dead_zone", "load_torque"}): (
        "compare a coast-down (no command, the load still acts) with a low-voltage staircase"
    ),
    frozenset({"current_offset", "brush_drop"}): (
        "read the current with the armature open: an offset reads non-zero"
    ),
    frozenset({"current_offset", "dead_zone"}): (
        "read the current with the armature open: an offset reads non-zero"
    ),
    frozenset({"cogging", "coulomb_friction"}): (
        "a slow run over several turns: cogging repeats with the shaft angle"
    ),
    frozenset({"cogging", "stribeck_friction"}): (
        "a slow run over several turns: cogging repeats with the shaft angle"
    ),
    frozenset({"resistance_drift", "load_torque"}): (
        "repeat the first test at the end of the run: a drift makes the two differ"
    ),
    frozenset({"resistance_drift", "coulomb_friction"}): (
        "repeat the first test at the end of the run: a drift makes the two differ"
    ),
    frozenset({"resistance_drift", "current_offset"}): (
        "read the current with the armature open at the start and the end of the run"
    ),
    frozenset({"inductance_saturation", "brush_drop"}): (
        "steps to a low and a high current, sampled at >= 10 samples per L/R: saturation "
        "speeds up only the high-current rise"
    ),
    frozenset({"delay", "dead_zone"}): (
        "a small sweep around a held offset and a large step: a delay shifts both in time, "
        "a dead zone removes only small commands"
    ),
    frozenset({"delay", "current_offset"}): (
        "read the current with the armature open: an offset reads non-zero, a delay does not"
    ),
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
