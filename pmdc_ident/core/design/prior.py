"""What the designer believes before the experiment: a motor model and the rig's noise.

A prior comes from a motor file (a built-in motor, or the YAML ``identify --yaml``
writes), or from a short pre-test identified on the rig (:mod:`.pretest`). The model
is simulated with every effect it carries (a Coulomb friction holds the rotor at
rest, a delay delays) to predict currents, speeds and travel; the information is that
of the model ``identify`` fits (linear, ``Kt = Ke``, plus a Coulomb torque when the
prior has one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from pmdc_ident.core.design.information import Noise
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import MotorSpec

__all__ = ["Prior", "noise_from_sensors"]


def noise_from_sensors(
    current_noise_a: float,
    speed_noise_rad_s: float,
    counts_per_rev: float,
    source: str = "the prior",
) -> Noise:
    """The rig's noise: a measured speed when it has one, else the encoder's angle
    (quantisation q / sqrt(12))."""
    if not (math.isfinite(current_noise_a) and current_noise_a >= 0):
        msg = f"current noise must be a number >= 0 A, got {current_noise_a}"
        raise ParameterError(msg)
    pos_sd = 0.0
    if counts_per_rev > 0:
        pos_sd = 2.0 * math.pi / counts_per_rev / math.sqrt(12.0)
    if speed_noise_rad_s <= 0 and pos_sd <= 0:
        msg = (
            f"{source} gives neither a speed noise nor an encoder resolution: give "
            f"{opt('speed_noise')} RAD_S (a measured speed) or {opt('counts_per_rev')} N (an "
            "encoder)"
        )
        raise ParameterError(msg)
    if current_noise_a <= 0:
        msg = (
            f"{source} gives no current noise: give {opt('current_noise')} A (the current "
            "sensor's standard deviation per sample)"
        )
        raise ParameterError(msg)
    return Noise(float(current_noise_a), float(max(speed_noise_rad_s, 0.0)), pos_sd)


@dataclass(frozen=True)
class Prior:
    """The motor as believed, the rig's noise and where both come from."""

    model: Model
    noise: Noise
    source: str

    @classmethod
    def from_spec(
        cls,
        spec: MotorSpec,
        *,
        current_noise_a: float | None = None,
        speed_noise_rad_s: float | None = None,
        counts_per_rev: float | None = None,
        source: str | None = None,
    ) -> Prior:
        s = spec.sensors
        noise = noise_from_sensors(
            s.current_noise_a if current_noise_a is None else current_noise_a,
            s.speed_noise_rad_s if speed_noise_rad_s is None else speed_noise_rad_s,
            s.encoder_counts_per_rev if counts_per_rev is None else counts_per_rev,
            source or f"motor {spec.name}",
        )
        return cls(spec.model, noise, source or f"motor {spec.name}")

    @property
    def coulomb_nm(self) -> float:
        e = self.model.effect("coulomb_friction")
        return float(getattr(e, "torque_nm", 0.0)) if e is not None else 0.0

    @property
    def breakaway_nm(self) -> float:
        """Torque that holds the rotor at rest (Coulomb plus Stribeck's extra)."""
        e = self.model.effect("stribeck_friction")
        return self.coulomb_nm + (float(getattr(e, "torque_nm", 0.0)) if e is not None else 0.0)

    def fitted_values(self) -> dict[str, float]:
        """The values of the fitted model under the closure ``Kt = Ke``: the data show
        ``J/Kt``, ``B/Kt`` and ``Tc/Kt``, so J, B and Tc scale by ``Ke / Kt``."""
        p = self.model.params
        c = p.Ke / p.Kt
        return {
            "R": p.R,
            "L": p.L,
            "Ke": p.Ke,
            "J": p.J * c,
            "B": p.B * c,
            "Tc": self.coulomb_nm * c,
        }

    def pessimistic(self) -> Model:
        """A motor that draws more, runs faster and farther than the prior (R 10 % low,
        L a tenth: a current that follows every command at once, Ke 10 % low, J 20 % low,
        friction halved): the session's aborts and the travel range hold for it too. A
        pre-test's L, in particular, is often far from the truth where L/R is below the
        sample period."""
        p = self.model.params
        q = p.replace(
            R=0.9 * p.R, L=0.1 * p.L, Ke=0.9 * p.Ke, Kt=0.9 * p.Kt, J=0.8 * p.J, B=0.5 * p.B
        )
        effects = []
        for e in self.model.effects:
            if e.NAME in ("coulomb_friction", "stribeck_friction"):
                e = replace(e, torque_nm=0.5 * e.torque_nm)
            effects.append(e)
        return Model(q, tuple(effects))

    def describe(self) -> str:
        p = self.model.params
        tc = f", Tc {self.coulomb_nm:.3g} N*m" if self.coulomb_nm > 0 else ""
        return (
            f"{self.source}: R {p.R:.4g} ohm, L {p.L:.3g} H, Ke {p.Ke:.4g} V*s/rad, "
            f"J {p.J:.3g} kg*m^2, B {p.B:.3g} N*m*s/rad{tc}; tau_m "
            f"{p.mechanical_time_constant_s * 1e3:.3g} ms; noise {self.noise.describe()}"
        )
