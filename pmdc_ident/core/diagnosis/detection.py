"""What a record could have shown: per effect, the smallest size these data would reveal.

A ``no_gap`` verdict means "nothing this record could show", not "nothing there". For
each effect of the vocabulary this module finds the size at which it would have left a
held-out gap the diagnosis calls: the baseline motor plus the effect at that size is
simulated on the record's own commands, segment by segment from their initial states
(:func:`~.candidates.predict`); the linear model refitted to that signature on the fit
segments (to first order: least squares on the baseline's sensitivities to R, L, Ke,
J, B and each fit segment's initial current and speed) absorbs what it can; what is
left on the held-out segments, in noise variances per signal and averaged as the gap
is (:mod:`.scoring`), must reach the verdict's threshold: one noise variance plus the
penalty of the effect's parameters. Both sides of the split are tried (the diagnosis
looks with them swapped when the default finds nothing), and the smaller size stands;
the swapped side's only where the diagnosis would take what it shows
(:func:`~.pipeline._swapped_look`): where the effect leaves the default side's own
baseline a misfit on its fit segments above ``no_gap_noise`` (a gap no candidate closes
is then reported), or leaves one there on the swapped side's fit segments (there a
candidate fitted can close it). An effect confined to a segment the default split fits
(the breakaway from rest of a Stribeck fall on MuJoCo's LuGre curve) is otherwise
judged shown on the swapped side at a size the diagnosis reports ``no_gap`` for. A
user's split is judged on its own side only (the diagnosis looks no further).

Sizes are reported in the effect's own unit and relative to the record: torques to the
motor's peak torque on the record (Kt x its largest current), voltages to its largest
command, a delay in samples, an offset to the largest current, a resistance drift as
the rise of R over the record's heat, an inductance saturation as the fall of L at the
record's largest current. Cogging is found for several periods per turn (those the
record's speeds resolve) and the largest size is reported: none above it, whatever the
number of periods. A delay is never below 1/pi sample (the verdict reads that as the
signal chain's lag). A size above the effect's physical range, or where the record
cannot show the effect at all, is reported as ``None`` with the reason.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis.candidates import predict
from pmdc_ident.core.diagnosis.holdout import HoldoutSplit
from pmdc_ident.core.diagnosis.scoring import NoiseModel, simulated
from pmdc_ident.core.diagnosis.verdict import Thresholds
from pmdc_ident.core.effects import EFFECT_TYPES, DetectionProbe, Effect, RecordScales
from pmdc_ident.core.model import Model

__all__ = ["DetectionLimit", "detection_limits", "limits_line", "with_detection_limits"]

FloatArray = NDArray[np.float64]
_PARAMS = ("R", "L", "Ke", "J", "B")
_STEP = 1e-4
COGGING_PERIODS = (4, 16, 48)  # per measured turn, where the record resolves them
MAX_RELATIVE = 10.0  # beyond 10x the record's own scale: not shown at any plausible size


@dataclass(frozen=True)
class DetectionLimit:
    """The smallest size of one effect this record would have shown (``None``: none)."""

    effect: str
    size: float | None  # in ``unit``
    unit: str
    relative: float | None  # size / the record's scale below
    relative_to: str
    detail: str = ""

    def to_json(self) -> dict[str, object]:
        return {
            "size": self.size,
            "unit": self.unit,
            "relative": self.relative,
            "relative_to": self.relative_to,
            "detail": self.detail,
        }

    def text(self) -> str:
        if self.size is None:
            return f"{self.effect} not shown at any size ({self.detail})"
        rel = f" ({100 * self.relative:.2g} % of {self.relative_to})" if self.relative else ""
        return f"{self.effect} {self.size:.3g} {self.unit}{rel}"


class _Record:
    """The baseline's signals and sensitivities on every segment, and both sides of the
    split: an effect's signature is simulated once per size and judged on each side."""

    def __init__(
        self,
        model: Model,
        split: HoldoutSplit,
        noise: NoiseModel,
        misfit: float = 1.0,
        *,
        swap: bool = True,
    ) -> None:
        self.model, self.noise, self.misfit = model, noise, misfit
        self.segs = (*split.fit, *split.held_out)
        self.sigs = tuple(noise.signals)
        self.y0 = self.signals(model)
        self.dpar = []  # per parameter, per segment: {sig: weighted sensitivity}
        for name in _PARAMS:
            v = getattr(model.params, name)
            q = model.params.replace(**{name: v * (1.0 + _STEP)})
            if name == "Ke":
                q = q.replace(Kt=model.params.Kt * (1.0 + _STEP))
            y = self.signals(Model(q, model.effects))
            self.dpar.append(
                [{k: (a[k] - b[k]) / _STEP for k in a} for a, b in zip(y, self.y0, strict=True)]
            )
        self.dx0 = [self._x0_columns(seg) for seg in self.segs]
        n_fit = len(split.fit)
        idx = list(range(len(self.segs)))
        self.sides = [(idx[:n_fit], idx[n_fit:]), (idx[n_fit:], idx[:n_fit])]
        # the default split's side first; a user's split has no second look
        if split.rule == "swapped":
            self.sides.reverse()
        elif split.rule != "default" or not swap:
            self.sides = self.sides[:1]
        # the refit's least squares, solved once per side: theta = P d (and D, to
        # leave the fit segments' own misfit)
        self.D = [self._design(fit) for fit, _ in self.sides]
        self.P = [np.linalg.pinv(d) for d in self.D]

    def signals(self, model: Model) -> list[dict[str, FloatArray]]:
        out = []
        for seg, pr in zip(self.segs, predict(model, self.segs), strict=True):
            d = {}
            for sig in self.sigs:
                meas = seg.current if sig == "current" else seg.speed_or_derivative()
                if meas is not None:
                    d[sig] = np.nan_to_num(simulated(seg, pr, sig)) / self.noise.sigma[sig]
            out.append(d)
        return out

    def _x0_columns(self, seg: Segment) -> list[dict[str, FloatArray]]:
        """The segment's response to its initial current and speed (the fit frees them)."""
        from pmdc_ident.core.model import simulate

        v = seg.voltage if seg.voltage is not None else np.full(seg.n, math.nan)
        cols = []
        for idx in (0, 1):
            x0 = np.zeros(3)
            x0[idx] = 1.0
            a = simulate(
                Model(self.model.params),
                np.where(np.isfinite(v), 0.0, v),
                seg.dt_s,
                x0=x0,
                substeps=1,
            )
            d = {}
            for sig in self.sigs:
                meas = seg.current if sig == "current" else seg.speed_or_derivative()
                if meas is not None:
                    d[sig] = np.asarray(simulated(seg, a, sig), float) / self.noise.sigma[sig]
            cols.append(d)
        return cols

    def _stack(self, idx: Sequence[int], per_seg: Sequence[dict[str, FloatArray]]) -> FloatArray:
        parts = [per_seg[k][sig] for sig in self.sigs for k in idx if sig in per_seg[k]]
        return np.concatenate(parts) if parts else np.zeros(0)

    def _design(self, fit: Sequence[int]) -> FloatArray:
        cols = [self._stack(fit, d) for d in self.dpar]
        for k in fit:
            for col in self.dx0[k]:
                one = [
                    col if j == k else {s: np.zeros_like(a) for s, a in self.y0[j].items()}
                    for j in range(len(self.segs))
                ]
                cols.append(self._stack(fit, one))
        return np.column_stack(cols)

    def gap(self, model: Model) -> float:
        """The held-out gap the effect leaves once the linear refit on the fit side has
        absorbed what it can: the default side's, or the swapped side's where larger and
        the diagnosis would take it (see the module notes)."""
        per = self.gaps(model)
        gap, misfit = per[0]
        if len(per) > 1:
            gap2, misfit2 = per[1]
            if max(misfit, misfit2) > self.misfit:
                gap = max(gap, gap2)
        return gap

    def gaps(self, model: Model) -> list[tuple[float, float]]:
        """Per side: the held-out gap and the misfit on the fit segments themselves (both
        in noise variances, averaged over the signals) once the refit has absorbed what
        it can."""
        y = self.signals(model)
        d = [{k: a[k] - b[k] for k in a} for a, b in zip(y, self.y0, strict=True)]
        out = []
        for (fit, ho), P, D in zip(self.sides, self.P, self.D, strict=True):
            d_fit = self._stack(fit, d)
            theta = P @ d_fit
            r_fit, misfit, at = d_fit - D @ theta, [], 0
            for sig in self.sigs:
                n = sum(d[k][sig].size for k in fit if sig in d[k])
                if n:
                    misfit.append(float(np.mean(r_fit[at : at + n] ** 2)))
                at += n
            parts = []
            for sig in self.sigs:
                segs = [k for k in ho if sig in d[k]]
                if not segs:
                    continue
                r = np.concatenate([d[k][sig] for k in segs])
                r = r - sum(
                    theta[j] * np.concatenate([self.dpar[j][k][sig] for k in segs])
                    for j in range(len(_PARAMS))
                )
                parts.append(float(np.mean(r**2)))
            out.append(
                (
                    float(np.mean(parts)) if parts else 0.0,
                    float(np.mean(misfit)) if misfit else 0.0,
                )
            )
        return out


def _scales(segments: Sequence[Segment], model: Model) -> RecordScales:
    cur = np.concatenate([s.current for s in segments if s.current is not None] or [np.zeros(1)])
    v = np.concatenate([s.voltage for s in segments if s.voltage is not None] or [np.zeros(1)])
    w = np.concatenate([s.speed_or_derivative() for s in segments])
    heat = sum(
        float(np.sum(np.where(s.open_mask, 0.0, s.current) ** 2) * s.dt_s)
        for s in segments
        if s.current is not None
    )
    i_pk = max(float(np.max(np.abs(cur))), 1e-9)
    return RecordScales(
        peak_torque_nm=model.params.Kt * i_pk,
        peak_voltage_v=max(float(np.nanmax(np.abs(v))) if np.isfinite(v).any() else 0.0, 1e-9),
        peak_current_a=i_pk,
        top_speed_rad_s=max(float(np.max(np.abs(w))), 1e-9),
        heat_a2s=max(heat, 1e-12),
        dt_s=float(np.median([s.dt_s for s in segments])),
    )


def _cogging_periods(segments: Sequence[Segment], sc: RecordScales) -> list[float]:
    """Periods per measured turn the record's speeds resolve (cogging's frequency at the
    typical moving speed below a quarter of the sample rate) and its turns cover."""
    w = np.abs(np.concatenate([s.speed_or_derivative() for s in segments]))
    moving = w[w > 0.02 * sc.top_speed_rad_s]
    if moving.size == 0:
        return []
    pos = [s.position for s in segments if s.position is not None]
    turned = max((float(np.ptp(p)) for p in pos), default=float(np.sum(w) * sc.dt_s))
    w_typ = float(np.median(moving))
    out = []
    for n in COGGING_PERIODS:
        if n * w_typ / (2 * math.pi) > 0.25 / sc.dt_s:
            continue
        if turned * n / (2 * math.pi) < 2.0:
            continue  # fewer than two periods passed the shaft
        out.append(float(n))
    return out


def _limit(spec: DetectionProbe, base: Model, rec: _Record, need: float) -> float | None:
    """The smallest size whose held-out gap reaches ``need`` on either side."""
    upper = spec.largest if spec.largest is not None else MAX_RELATIVE * spec.scale

    def g(s: float) -> float:
        try:
            return rec.gap(base.with_effects(spec.make(min(s, upper))))
        except Exception:  # noqa: BLE001 - a size outside the effect's range: not shown
            return 0.0

    s = spec.first
    gs = g(s)
    if spec.linear and gs > 0:
        # the gap grows with the size squared: one step there, one check
        s = s * math.sqrt(need / gs)
        if s > upper:
            return None
        gs = g(s)
        if 0.7 * need <= gs <= 1.5 * need:
            return s
    lo, hi = None, None
    for _ in range(20):  # bracket by factors of 4, then bisect (the gap grows with size)
        if gs >= need:
            hi = s
            if lo is not None:
                break
            s /= 4.0
        else:
            lo = s
            if hi is not None:
                break
            s *= 4.0
        if s > 4.0 * upper or s < 1e-9 * spec.scale:
            break
        gs = g(s)
    if hi is None or hi > upper:
        return None
    if lo is not None:
        for _ in range(4):
            mid = math.sqrt(lo * hi)
            if g(mid) >= need:
                hi = mid
            else:
                lo = mid
    return hi


def detection_limits(
    split: HoldoutSplit,
    base: Model,
    noise: NoiseModel,
    thresholds: Thresholds,
    effects: Sequence[str],
    *,
    swap: bool = True,
) -> tuple[DetectionLimit, ...]:
    """Per effect of ``effects``, the smallest size this record would have shown (see
    the module notes); ``base`` is the baseline's fitted linear model; ``swap``: the
    diagnosis looks with the sides swapped (its ``DiagnosisConfig.swap``)."""
    segs = (*split.fit, *split.held_out)
    sc = _scales(segs, base)
    sc = replace(sc, periods_per_turn=tuple(_cogging_periods(segs, sc)))
    rec = _Record(base, split, noise, thresholds.no_gap_noise, swap=swap)
    return tuple(
        _detection_limit(EFFECT_TYPES[name], sc, base, rec, thresholds) for name in effects
    )


def _detection_limit(
    cls: type[Effect], sc: RecordScales, base: Model, rec: _Record, thresholds: Thresholds
) -> DetectionLimit:
    """One effect's limit: the largest over its probes (the effect's own hooks)."""
    probes = cls.detection_probes(sc)
    if not probes:
        unit = next(iter(cls.SPECS.values())).unit  # the size's unit: its first field's
        return DetectionLimit(cls.NAME, None, unit, None, "", cls.DETECTION_NOT_SHOWN)
    found: list[float] = []
    for probe in probes:
        need = thresholds.no_gap_noise + thresholds.penalty_noise_per_param * probe.n_params
        lim = _limit(probe, base, rec, need)
        if lim is None:
            first = probes[0]
            why = f"not shown below {MAX_RELATIVE:g} x {first.relative_to}"
            return DetectionLimit(cls.NAME, None, first.unit, None, first.relative_to, why)
        found.append(max(lim, cls.detection_floor(sc)))
    size, first = max(found), probes[0]
    return DetectionLimit(
        cls.NAME, size, first.unit, size / first.scale, first.relative_to, cls.detection_detail(sc)
    )


def limits_line(limits: Sequence[DetectionLimit]) -> str:
    """'none above these sizes: coulomb_friction 0.0012 N*m (0.8 % of ...), ...'."""
    return "none above these sizes: " + "; ".join(lim.text() for lim in limits)


def limits_json(limits: Sequence[DetectionLimit]) -> Mapping[str, object]:
    return {lim.effect: lim.to_json() for lim in limits}


def with_detection_limits(result: Any, noise: NoiseModel, cfg: Any) -> Any:
    """The diagnosis' result with its detection limits (the hook in the pipeline); a
    ``no_gap`` verdict then reads "none above these sizes"."""
    from pmdc_ident.core.diagnosis.results import VerdictStatus
    from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams

    if result.detection_limits:
        return result  # computed with the verdict (``pipeline._showable``): the same
    values = {p.name: p.value for p in result.baseline if p.name in PARAMETER_NAMES}
    try:
        base = Model(MotorParams(**values))
        limits = detection_limits(
            result.split, base, noise, cfg.thresholds, cfg.effects, swap=cfg.swap
        )
    except Exception:  # noqa: BLE001 - the verdict stands without them
        return result
    if result.verdict.status is VerdictStatus.NO_GAP:
        verdict = replace(
            result.verdict, message=f"{result.verdict.message}; {limits_line(limits)}"
        )
        result = replace(result, verdict=verdict)
    return replace(result, detection_limits=limits)
