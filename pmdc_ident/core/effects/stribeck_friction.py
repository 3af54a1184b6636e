"""``stribeck_friction``: extra breakaway torque at low speed, falling with speed."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from pmdc_ident.core.effects import layout
from pmdc_ident.core.effects.base import (
    PEAK_TORQUE,
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

# exp(-x) ~ sum a exp(-(x/b)^2) for x >= 0, sum a = 1 (the breakaway torque exact):
# least squares, reweighted towards the largest error, on a uniform grid of x in
# [0, 15], fitted once to the function itself (no data); its largest error is
# EXPONENTIAL_FIT_ERROR (one Gaussian of the same area: 22 %, three: 3.4 %, which left
# the 24 V scooter's held-out current 0.019 A RMS off the model's on a slow staircase)
EXPONENTIAL_AS_GAUSSIANS: tuple[tuple[float, float], ...] = (
    (0.1177, 0.0902),
    (0.2614, 0.4204),
    (0.4044, 1.1336),
    (0.2165, 2.513),
)
EXPONENTIAL_FIT_ERROR = 0.016
DETECTION_SPEED = 0.05  # the detection limit's Stribeck speed, of the record's top speed

__all__ = ["StribeckFriction"]


@dataclass(frozen=True)
class StribeckFriction(Effect):
    NAME: ClassVar[str] = "stribeck_friction"
    DESCRIPTION: ClassVar[str] = "extra breakaway torque at low speed"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "torque_nm": ParamSpec("N*m", 0.0, 1e4, "extra breakaway torque at rest"),
        "speed_rad_s": ParamSpec("rad/s", 1e-3, 1e4, "Stribeck speed"),
        # the shape of the fall: 1 Tustin's exponential, 2 the Gaussian (Armstrong);
        # measured curves lie between (a setting the diagnosis scans, not a fitted value)
        "shape_exponent": ParamSpec(
            "1", 0.5, 2.0, "exponent d of the fall exp(-(|w|/ws)^d)", False
        ),
    }
    KERNEL_SLOTS = {"torque_nm": layout.TS, "speed_rad_s": layout.WS, "shape_exponent": layout.DS}
    KERNEL_NEUTRAL = {layout.WS: 1.0, layout.DS: 2.0}
    SIM_PATH = SimPath.FAST
    FAST_COLUMNS = {"torque_nm": layout.COL_TS, "speed_rad_s": layout.COL_WS}
    PRIOR = 40
    # the coarse scan cannot tell the shape from a misplaced Stribeck speed; the fits can
    SETTING_SCAN = ("shape_exponent", (1.0, 2.0))
    SEPARATING_TESTS = {
        "load_torque": (
            "run in reverse and a slow staircase near zero speed: Stribeck friction changes "
            "sign with the direction and falls off with speed, a load torque does neither"
        ),
        "quadratic_drag": (
            "a staircase from near zero to full speed: Stribeck friction falls with speed, "
            "drag grows with its square"
        ),
    }
    REVEAL = "stribeck_staircase"
    BENCHMARK_LADDER = Ladder("% rated torque", (6.0, 12.0, 25.0, 50.0))
    MUJOCO_MAPPING = (
        '`<dcmotor lugre="sigma0 0 Fc Fc+Ts vs">`: LuGre\'s Gaussian Stribeck curve '
        "g(v) = Fc + Ts exp(-(v/vs)^2), vs = ws for the Gaussian fall (shape 2); the exponential "
        "one (shape 1) as four Gaussian falls (a Ts, b ws) with (a, b) = (0.118, 0.090), "
        "(0.261, 0.420), (0.404, 1.13), (0.217, 2.51) (within 1.6 % of Ts at every speed), "
        'the second to fourth on passive `<dcmotor input="none">` elements; Fc the Coulomb '
        "friction's torque, at least 1e-6 Ts (MuJoCo's bristle equation divides by g); "
        "bristles as stiff as the model's step resolves (their resonance with the rotor "
        "sqrt(sigma0/J) x step = 0.3), undamped (MuJoCo's bristle damping makes the friction "
        "depend on the step)"
    )

    torque_nm: float
    speed_rad_s: float
    shape_exponent: float = 2.0

    @classmethod
    def detection_probes(cls, sc: RecordScales) -> list[DetectionProbe]:
        # both common shapes of the fall at one Stribeck speed, the larger limit stands:
        # at the same speed the Gaussian fall (MuJoCo's LuGre curve) acts over fewer
        # speeds than the exponential one and may need a larger torque to show
        t, w = sc.peak_torque_nm, sc.top_speed_rad_s
        return [
            DetectionProbe(
                lambda s, d=shape: cls(s, max(DETECTION_SPEED * w, 1e-3), d),
                0.05 * t,
                "N*m",
                t,
                PEAK_TORQUE,
                2,
                False,
            )
            for shape in (1.0, 2.0)
        ]

    @classmethod
    def detection_detail(cls, sc: RecordScales) -> str:
        return (
            f"the larger of an exponential and a Gaussian fall at {DETECTION_SPEED:.0%} of "
            "the top speed; a slower fall shows less"
        )

    @classmethod
    def starts(cls, sc: DataScales) -> list[StribeckFriction]:
        # the fall's speed over two decades of the top speed, in both common shapes
        # (exponential and Gaussian: measured curves lie between); the fit places the
        # torque, a start need only be of its order
        return [
            cls.clipped(sc.torque_nm * 0.25, max(sc.speed_rad_s * g, 1e-3), shape)
            for shape in (1.0, 2.0)
            for g in (0.005, 0.02, 0.08, 0.3)
        ]

    def mujoco_terms(self, ctx: MujocoContext) -> MujocoTerms:
        # MuJoCo's Stribeck fall is Gaussian; the exponential one maps to a sum of
        # Gaussian falls (EXPONENTIAL_AS_GAUSSIANS), each but the first a passive element
        if self.shape_exponent >= 1.5:
            return MujocoTerms(stribeck=(self.torque_nm, self.speed_rad_s))
        parts = tuple(
            (a * self.torque_nm, b * self.speed_rad_s) for a, b in EXPONENTIAL_AS_GAUSSIANS
        )
        partial = (
            f"the exponential fall's shape (carried as the sum of {len(parts)} Gaussian falls, "
            f"within {EXPONENTIAL_FIT_ERROR:.1%} of the Stribeck torque at every speed: "
            "MuJoCo's LuGre curve is Gaussian)"
        )
        return MujocoTerms(stribeck=parts[0], stribeck_more=parts[1:], partial=partial)
