"""``resistance_drift``: the winding heats, R rises (and the magnets may lose flux)."""

from __future__ import annotations

from collections.abc import MutableSequence
from dataclasses import dataclass
from typing import ClassVar

from pmdc_ident.core.effects import layout
from pmdc_ident.core.effects.base import (
    DataScales,
    DetectionProbe,
    Effect,
    Ladder,
    MujocoContext,
    MujocoTerms,
    ParamSpec,
    RecordScales,
    SimPath,
)

__all__ = ["NO_COOLING_S", "ResistanceDrift"]

NO_COOLING_S = 1e6  # a winding time constant this long is the plain heat integral
ALPHA_COPPER = 0.00393  # 1/K: the temperature coefficient the MuJoCo export writes


@dataclass(frozen=True)
class ResistanceDrift(Effect):
    NAME: ClassVar[str] = "resistance_drift"
    DESCRIPTION: ClassVar[str] = (
        "winding heats, R rises: first-order heating by i^2 with a thermal time constant"
        " (the magnets' flux may fall with it)"
    )
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        # k = alpha R / C_th: 0.004 1/K x R over the winding's heat capacity; a coreless
        # micro-motor (20-100 ohm, 0.01-0.05 J/K) reaches 10-40, a milliamp one more
        "coeff_per_a2s": ParamSpec("1/(A^2*s)", 0.0, 1e4, "k in R(t) = R (1 + k q)"),
        "time_constant_s": ParamSpec(
            "s",
            0.1,
            NO_COOLING_S,
            "winding thermal time constant (dq/dt = i^2 - q/tau)",
            limit=NO_COOLING_S,
        ),
        # the magnets heat with the winding and lose flux: Ke(t) = Ke (1 - r k q), Kt
        # likewise. r is the relative fall of the flux per relative rise of R: a
        # magnet's coefficient over copper's (+0.39 %/K) times the magnets' temperature
        # rise over the winding's. NdFeB (-0.12 %/K) gives 0.31, ferrite (-0.2 %/K,
        # the steepest common magnet) 0.51, SmCo 0.09, each when the magnets get as hot
        # as the winding; they heat less and later (heated through the air gap, more
        # mass), so a physical r stays below ~0.5. The bound 1 (the flux never falls
        # faster than R rises) leaves room for the one heat state standing in for the
        # magnets' own. 0 is the limit: no weakening.
        "flux_loss_ratio": ParamSpec(
            "1", 0.0, 1.0, "r in Ke(t) = Ke (1 - r k q), Kt likewise", limit=0.0
        ),
    }
    KERNEL_SLOTS = {"coeff_per_a2s": layout.KR}  # and TAUQ, KF: see write_coefficients
    SIM_PATH = SimPath.REDISCRETISED
    PRIOR = 100
    # the heat integral first, then first-order heating with its time constant; heating
    # that helps once more with the magnets losing flux in its heat (a quarter of the
    # relative rise of R, between NdFeB's 0.31 and half of it: magnets cooler than the
    # winding)
    SECOND_FORM = "time_constant_s"
    FURTHER_FORM = ("flux_loss_ratio", 0.2)
    SEPARATING_TESTS = {
        "brush_drop": (
            "repeat the staircase at the end of the run: drift makes it differ from the first"
        ),
        "load_torque": "repeat the first test at the end of the run: a drift makes the two differ",
        "coulomb_friction": (
            "repeat the first test at the end of the run: a drift makes the two differ"
        ),
        "current_offset": (
            "read the current with the armature open at the start and the end of the run"
        ),
    }
    REVEAL = "hot_hold"
    BENCHMARK_LADDER = Ladder("% of R", (4.0, 8.0, 16.0, 32.0))
    MUJOCO_MAPPING = (
        "`<dcmotor thermal=\"R_th C 0 alpha' 25+D 25\">` with copper's alpha = 0.00393/K: "
        "C = alpha R / k, R_th = tau / C (no cooling: tau 1e6 s), so alpha T = k q to first "
        "order (MuJoCo heats by R(T) i^2 where the candidate heats by R i^2); MuJoCo keeps "
        "L/R as R heats, so its L is the winding's at one reference rise D only: resistance "
        "R (1 + alpha D) and alpha' = alpha / (1 + alpha D) keep R(T), C (1 + alpha D) and "
        "R_th / (1 + alpha D) make the heating rate the candidate's at D; D = 0 (ambient) "
        "by default, `roundtrip` the rise whose MuJoCo replay of the diagnosis' fit "
        "segments matches their record best (the held-out data never choose it); the "
        "magnets' flux loss r is not carried"
    )

    coeff_per_a2s: float
    time_constant_s: float = NO_COOLING_S  # the plain integral within any run
    flux_loss_ratio: float = 0.0  # magnets that keep their flux

    def write_coefficients(self, c: MutableSequence[float]) -> None:
        c[layout.KR] = self.coeff_per_a2s
        c[layout.KF] = self.flux_loss_ratio * self.coeff_per_a2s  # Ke (1 - kf q)
        # 0: no cooling (the kernel integrates the heat)
        c[layout.TAUQ] = self.time_constant_s if self.time_constant_s < NO_COOLING_S else 0.0

    def varies_within_sample(self) -> bool:
        return self.coeff_per_a2s > 0.0

    def mujoco_terms(self, ctx: MujocoContext) -> MujocoTerms:
        # alpha dT/dt = alpha R' i'^2 / C must be k i^2, with MuJoCo's current i' = s i
        c = (
            ALPHA_COPPER
            * ctx.resistance_ohm
            * ctx.current_scale**2
            / max(self.coeff_per_a2s, 1e-30)
        )
        partial = ""
        if self.flux_loss_ratio > 0:
            partial = (
                f"the magnets' flux loss (flux_loss_ratio {self.flux_loss_ratio:.3g}: MuJoCo's "
                "motor constant does not follow the heat)"
            )
        return MujocoTerms(thermal=(self.time_constant_s / c, c, ALPHA_COPPER), partial=partial)

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        heat = sc.heat_a2s
        return [
            DetectionProbe(
                lambda s: cls(s / heat), 0.02, "rise of R over the record", 1.0, "R", 1, False
            )
        ]

    @classmethod
    def starts(cls, sc: DataScales) -> list[ResistanceDrift]:
        # first-order heating: q levels off near (mean i^2) x tau when tau < the span;
        # magnets that keep their flux (the diagnosis frees that only where heating helps)
        power = sc.charge_a2s / sc.span_s
        return [
            cls.clipped(f / (power * min(tau, sc.span_s)), tau, 0.0)
            for f in (0.05, 0.2)
            for tau in (0.25 * sc.span_s, sc.span_s, NO_COOLING_S)
        ]
