"""The round trip: a diagnosis exported to MuJoCo and checked there on held-out data.

:func:`round_trip` takes a :class:`~pmdc_ident.core.diagnosis.DiagnosisResult` (what
``diagnose`` found on a recorded run), exports two MJCF models with
:func:`~pmdc_ident.exports.mujoco_xml.mujoco_xml` - the plain one (the diagnosis'
linear baseline) and the one with the diagnosis (its model with every named effect
MuJoCo carries, :func:`~pmdc_ident.exports.diagnosis.motor_with_diagnosis`) - replays
the recorded voltage of every held-out segment in MuJoCo (:mod:`.mujoco_replay`), and
measures the held-out gap of each exactly as the diagnosis does: the same segments,
the same lead-ins, the same noise levels, the same gap (excess squared error in noise
variances, averaged over current and speed). The same two models are simulated by the
project's own simulator on the same segments, so the two shrinks compare the
simulators and nothing else: a MuJoCo shrink close to the project's says the effect
went into MuJoCo as the diagnosis found it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import minimize_scalar

from pmdc_ident.core.data import Segment, heat_state
from pmdc_ident.core.diagnosis import DiagnosisResult
from pmdc_ident.core.diagnosis.leadin import lead_ins
from pmdc_ident.core.diagnosis.scoring import NoiseModel, residuals
from pmdc_ident.core.effects import ResistanceDrift
from pmdc_ident.core.effects.resistance_drift import ALPHA_COPPER
from pmdc_ident.core.estimators.output_error.segments import x0_from_data
from pmdc_ident.core.estimators.output_error.simulators import general_sim
from pmdc_ident.core.model import Model, heat_time_constant
from pmdc_ident.core.motors import Limits, MotorSpec
from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams
from pmdc_ident.exports.diagnosis import motor_with_diagnosis
from pmdc_ident.exports.mujoco_replay import Replayed, SegmentStart, replay_segments
from pmdc_ident.exports.mujoco_xml import mujoco_xml

__all__ = ["DEFAULT_SUBSTEPS", "RoundTrip", "round_trip"]

DEFAULT_SUBSTEPS = 50  # MuJoCo steps per sample of the replay
REFERENCE_XATOL = 0.02  # the thermal reference's search: to 2 % of the largest rise


def _shrink(before: float, after: float) -> float:
    """As the diagnosis reports it: the share of the gap closed, at most 1."""
    if not (before > 0 and math.isfinite(before)):
        return 0.0
    return min(1.0, 1.0 - max(after, 0.0) / before)


@dataclass(frozen=True)
class RoundTrip:
    """The held-out gaps of the plain and the diagnosed model, in the project's simulator
    and in MuJoCo, and what the MJCF carries."""

    status: str
    effects: tuple[str, ...]  # named by the diagnosis
    carried: tuple[str, ...]  # of those, what the MJCF carries (effect names)
    not_carried: tuple[str, ...]  # lines: what the MJCF leaves out
    diagnosis_gap: tuple[float, float]  # the diagnosis' own (before, after)
    project_gap: tuple[float, float]  # the exported models in the project's simulator
    mujoco_gap: tuple[float, float]  # ... replayed in MuJoCo
    timestep_s: float
    held_out: tuple[str, ...]  # labels
    xml_plain: str = field(repr=False, default="")
    xml_diagnosed: str = field(repr=False, default="")

    @property
    def diagnosis_shrink(self) -> float:
        return _shrink(*self.diagnosis_gap)

    @property
    def project_shrink(self) -> float:
        return _shrink(*self.project_gap)

    @property
    def mujoco_shrink(self) -> float:
        return _shrink(*self.mujoco_gap)

    @property
    def difference_points(self) -> float:
        """MuJoCo's shrink minus the project's, in percentage points."""
        return 100.0 * (self.mujoco_shrink - self.project_shrink)

    def lines(self) -> list[str]:
        named = ", ".join(self.effects) or "none"
        carried = ", ".join(self.carried) or "none"
        out = [
            f"diagnosis: {self.status} ({named}); held-out gap {self.diagnosis_gap[0]:.3g} -> "
            f"{self.diagnosis_gap[1]:.3g} noise variances ({self.diagnosis_shrink:.0%} closed)",
            f"exported to MuJoCo: {carried} carried (step {self.timestep_s:.3g} s); held-out "
            f"segments {', '.join(self.held_out)} replayed with their recorded voltage",
            "held-out gap, noise variances:         plain export   export with the diagnosis"
            "   shrink",
            f"  the project's model (same exports)  {self.project_gap[0]:12.4g}   "
            f"{self.project_gap[1]:25.4g}   {self.project_shrink:6.1%}",
            f"  MuJoCo replay                        {self.mujoco_gap[0]:12.4g}   "
            f"{self.mujoco_gap[1]:25.4g}   {self.mujoco_shrink:6.1%}",
            f"MuJoCo's shrink minus the project's: {self.difference_points:+.1f} points",
        ]
        out += [f"  not carried: {line}" for line in self.not_carried]
        return out

    def to_json(self) -> dict[str, object]:
        def num(x: float) -> float | None:
            return x if math.isfinite(x) else None

        return {
            "status": self.status,
            "effects": list(self.effects),
            "carried": list(self.carried),
            "not_carried": list(self.not_carried),
            "held_out": list(self.held_out),
            "timestep_s": self.timestep_s,
            "gap_definition": (
                "held-out mean squared simulation error minus the noise variance, in noise "
                "variances, averaged over current and speed (as diagnose)"
            ),
            "diagnosis": {
                "gap_before": num(self.diagnosis_gap[0]),
                "gap_after": num(self.diagnosis_gap[1]),
                "shrink": num(self.diagnosis_shrink),
            },
            "project": {
                "gap_plain": num(self.project_gap[0]),
                "gap_diagnosed": num(self.project_gap[1]),
                "shrink": num(self.project_shrink),
            },
            "mujoco": {
                "gap_plain": num(self.mujoco_gap[0]),
                "gap_diagnosed": num(self.mujoco_gap[1]),
                "shrink": num(self.mujoco_shrink),
            },
            "difference_points": num(self.difference_points),
        }


def _params(estimates: Sequence[object]) -> MotorParams:
    by_name = {e.name: e.value for e in estimates}  # type: ignore[attr-defined]
    return MotorParams(**{k: float(by_name[k]) for k in PARAMETER_NAMES})


def _limits(segments: Sequence[Segment]) -> Limits:
    """Limits that never bind on the record: the export's ctrlrange and saturation."""

    def peak(name: str) -> float:
        parts = [getattr(s, name) for s in segments if getattr(s, name) is not None]
        xs = np.concatenate(parts) if parts else np.zeros(1)
        xs = xs[np.isfinite(xs)]
        return float(np.max(np.abs(xs))) if xs.size else 0.0

    speeds = [s.speed_or_derivative() for s in segments]
    w = max((float(np.nanmax(np.abs(x))) for x in speeds if x is not None and x.size), default=1.0)
    return Limits(
        voltage_max_v=max(1.05 * peak("voltage"), 1e-3),
        current_max_a=max(10.0 * peak("current"), 1e-3),
        speed_max_rad_s=max(2.0 * w, 1e-3),
    )


def _noise(result: DiagnosisResult, segments: Sequence[Segment]) -> NoiseModel:
    scale = {}
    for sig in result.noise_sigma:
        parts = [s.current if sig == "current" else s.speed_or_derivative() for s in segments]
        xs = np.concatenate([p for p in parts if p is not None])
        scale[sig] = float(np.sqrt(np.nanmean(xs**2)))
    return NoiseModel(dict(result.noise_sigma), scale)


def _start(seg: Segment, model: Model) -> SegmentStart:
    i0, w0, th0 = (float(x) for x in x0_from_data(seg))
    temp = 0.0
    drift = model.effect("resistance_drift")
    if isinstance(drift, ResistanceDrift) and drift.coeff_per_a2s > 0:
        q0 = heat_state(seg, heat_time_constant(model))
        temp = drift.coeff_per_a2s * q0 / ALPHA_COPPER  # alpha T = k q
    return SegmentStart(i0, w0, th0, temp)


def _model_rise(segments: Sequence[Segment], model: Model) -> float:
    """The largest rise above ambient (K) the model's heating reaches on ``segments``
    (``alpha T = k q``, ``dq/dt = i^2 - q/tau`` from each segment's start heat, the
    measured current held over each sample); 0 without heating."""
    drift = model.effect("resistance_drift")
    if not (isinstance(drift, ResistanceDrift) and drift.coeff_per_a2s > 0):
        return 0.0
    tau = heat_time_constant(model)
    top = 0.0
    for seg in segments:
        if seg.current is None or seg.n < 1:
            continue
        i2 = np.nan_to_num(seg.current, nan=0.0) ** 2
        if seg.voltage is not None:
            i2 = np.where(np.isnan(seg.voltage), 0.0, i2)
        decay = math.exp(-seg.dt_s / tau) if math.isfinite(tau) and tau > 0 else 1.0
        gain = tau * (1.0 - decay) if decay < 1.0 else seg.dt_s
        q = heat_state(seg, tau)
        top = max(top, q)
        for x in i2:
            q = q * decay + x * gain
            top = max(top, q)
    return max(0.0, drift.coeff_per_a2s * top / ALPHA_COPPER)


def thermal_reference(
    spec: MotorSpec,
    fit: Sequence[Segment],
    noise: NoiseModel,
    *,
    timestep_s: float,
    tau_s: float,
    current_scale: float = 1.0,
) -> float:
    """The winding's reference rise above ambient (K) for the MuJoCo export of ``spec``,
    fitted to the data the diagnosis fitted: MuJoCo keeps L/R as R heats, so its
    inductance is the winding's at one rise only (see
    :func:`~pmdc_ident.exports.mujoco_xml.mujoco_xml`); the rise chosen is the one whose
    MuJoCo replay of the fit segments ``fit`` (each from its own start, with a lead-in
    from the fit segment it continues, as held-out segments are predicted) matches their
    recorded current and speed best (the gap as ``diagnose`` measures it, ``noise``),
    searched between ambient and the largest rise the model's heating reaches on them.
    No held-out sample chooses it. 0 without heating."""
    top = _model_rise(fit, spec.model)
    if not top > 0:
        return 0.0
    leads = lead_ins(fit, fit, tau_s)
    starts = [_start(li.segment, spec.model) for li in leads]
    seen: dict[float, float] = {}

    def gap(rise: float) -> float:
        if rise in seen:
            return seen[rise]
        ex = mujoco_xml(spec, flavour="dcmotor", timestep_s=timestep_s, thermal_reference_k=rise)
        runs = replay_segments(
            ex.xml, [li.segment for li in leads], starts, current_scale=current_scale
        )
        preds = [_crop(r, li.samples) for r, li in zip(runs, leads, strict=True)]
        seen[rise] = residuals(fit, preds, noise).gap()
        return seen[rise]

    found = minimize_scalar(
        gap, bounds=(0.0, top), method="bounded", options={"xatol": REFERENCE_XATOL * top}
    )
    best = float(found.x)
    # the bounded search never tries its ends: ambient and the hottest rise compete too
    return min((best, 0.0, top), key=gap)


def _crop(pred: object, k: int) -> Replayed:
    return Replayed(
        pred.label,  # type: ignore[attr-defined]
        pred.t[k:],  # type: ignore[attr-defined]
        pred.current[k:],  # type: ignore[attr-defined]
        pred.speed[k:],  # type: ignore[attr-defined]
        pred.position[k:],  # type: ignore[attr-defined]
    )


def round_trip(result: DiagnosisResult, *, substeps: int = DEFAULT_SUBSTEPS) -> RoundTrip:
    """Export the diagnosis to MuJoCo, replay the held-out segments, compare the gaps."""
    split = result.split
    held = list(split.held_out)
    everything = [*split.fit, *held]
    base = Model(_params(result.baseline))
    plain = MotorSpec("roundtrip_plain", base, limits=_limits(everything))
    doc = result.to_json()
    diagnosed = motor_with_diagnosis(plain, doc, source="diagnosis", same_motor=False)
    spec = MotorSpec("roundtrip_diagnosed", diagnosed.spec.model, limits=plain.limits)
    tau = base.params.mechanical_time_constant_s
    leads = lead_ins(everything, held, tau)
    dt = float(np.median([s.dt_s for s in held]))
    h = dt / substeps
    noise = _noise(result, held)
    fit_noise = _noise(result, split.fit)

    def project_gap(model: Model) -> float:
        preds = []
        for li in leads:
            x = general_sim(model, li.segment, x0_from_data(li.segment))
            p = Replayed(li.segment.label, li.segment.t, x[:, 0], x[:, 1], x[:, 2])
            preds.append(_crop(p, li.samples))
        return residuals(held, preds, noise).gap()

    def mujoco_gap(s: MotorSpec) -> tuple[float, str, tuple[str, ...], tuple[str, ...]]:
        # heating: MuJoCo's inductance follows R, so the file is written with it exact
        # at the rise that replays the fit segments best (never chosen on held-out data)
        p = s.model.params
        rise = thermal_reference(
            s, split.fit, fit_noise, timestep_s=h, tau_s=tau, current_scale=p.Kt / p.Ke
        )
        ex = mujoco_xml(s, flavour="dcmotor", timestep_s=h, thermal_reference_k=rise)
        runs = replay_segments(
            ex.xml,
            [li.segment for li in leads],
            [_start(li.segment, s.model) for li in leads],
            current_scale=p.Kt / p.Ke,
        )
        preds = [_crop(r, li.samples) for r, li in zip(runs, leads, strict=True)]
        return residuals(held, preds, noise).gap(), ex.xml, ex.carried, ex.not_carried

    g_mj_plain, xml_plain, _, _ = mujoco_gap(plain)
    g_mj_diag, xml_diag, carried, not_carried = mujoco_gap(spec)
    named = set(diagnosed.effects)
    not_carried = tuple(
        line for line in not_carried if line.split(":", 1)[0] in named or line.startswith("Kt")
    )
    return RoundTrip(
        status=diagnosed.status,
        effects=diagnosed.effects,
        carried=tuple(c.split(":", 1)[0] for c in carried),
        not_carried=not_carried,
        diagnosis_gap=(result.gap_before, result.gap_after),
        project_gap=(project_gap(base), project_gap(spec.model)),
        mujoco_gap=(g_mj_plain, g_mj_diag),
        timestep_s=h,
        held_out=tuple(s.label for s in held),
        xml_plain=xml_plain,
        xml_diagnosed=xml_diag,
    )
