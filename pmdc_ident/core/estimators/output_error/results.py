"""What the output-error fit returns: :class:`FitResult` (values, intervals,
identifiability with reasons, free-run predictions) and how it is computed from the
solver's optimum (:func:`build_result`)."""

from __future__ import annotations

import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.effects import parameter_unit
from pmdc_ident.core.enums import ParameterNote
from pmdc_ident.core.estimators.output_error.problem import Problem
from pmdc_ident.core.estimators.output_error.segments import x0_from_data
from pmdc_ident.core.estimators.output_error.simulators import predict
from pmdc_ident.core.estimators.solver import LMState
from pmdc_ident.core.model import Model

__all__ = ["FitResult", "Prediction", "build_result"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Prediction:
    """Free-run simulation of one segment (arrays per sample, SI units)."""

    label: str
    t: FloatArray
    current: FloatArray
    speed: FloatArray
    position: FloatArray


@dataclass(frozen=True)
class FitResult:
    """Result of :func:`fit_output_error`.

    ``values`` holds every model parameter (free and fixed); ``ci95``/``stderr``
    are ``None`` for fixed or non-identifiable ones. ``covariance`` is over
    ``covariance_names`` (the free parameters, physical units). ``rms`` is the
    free-run residual RMS per fitted signal in its own unit; ``noise`` the
    per-signal noise level the residuals were scaled by.
    """

    model: Model
    values: dict[str, float]
    ci95: dict[str, tuple[float, float] | None]
    stderr: dict[str, float | None]
    covariance: FloatArray
    covariance_names: tuple[str, ...]
    identifiable: dict[str, bool]
    reasons: dict[str, str]
    cost: float
    n_samples: int
    rms: dict[str, float]
    noise: dict[str, float]
    free: tuple[str, ...]
    fixed: dict[str, float]
    closure: str | None
    initial_states: dict[str, tuple[float, float, float]]
    nfev: int
    iterations: int
    converged: bool
    message: str
    elapsed_s: float
    fast_path: bool
    warnings: tuple[str, ...] = ()
    added_inertia: dict[str, float] = field(default_factory=dict)
    # step of each quantised signal over the record (its first noise level >= step/sqrt(12))
    quantisation_steps: dict[str, float] = field(default_factory=dict)
    # what each reason says, by code (core.enums.ParameterNote)
    notes: dict[str, frozenset[ParameterNote]] = field(default_factory=dict)
    _fitted_segments: dict[str, int] = field(default_factory=dict, repr=False)

    def simulate_segments(
        self,
        segments: Sequence[Segment],
        *,
        use_fitted_initial_states: bool = True,
        added_inertia: Mapping[str, float] | None = None,
    ) -> list[Prediction]:
        """Free-run predictions of the fitted model on (possibly held-out) segments.

        The initial state is the fitted one for a segment of the fit (same label
        and length) and otherwise taken from the segment's first samples. A
        segment recorded with a known added inertia (``added_inertia``, by label;
        default: the fit's) is simulated with it.
        """
        out: list[Prediction] = []
        for seg in segments:
            x0 = x0_from_data(seg)
            key = seg.label
            if (
                use_fitted_initial_states
                and key in self.initial_states
                and self._fitted_segments.get(key) == seg.n
            ):
                x0 = np.array(self.initial_states[key], dtype=float)
            added = self.added_inertia if added_inertia is None else added_inertia
            x = predict(self.model, seg, x0, self.fast_path, float(added.get(key, 0.0)))
            out.append(Prediction(seg.label, seg.t.copy(), x[:, 0], x[:, 1], x[:, 2]))
        return out

    def summary(self) -> str:
        lines = [f"{'parameter':<28} {'value':>12}  {'95 % interval':<28} unit"]
        for name, value in self.values.items():
            ci = self.ci95.get(name)
            if name in self.fixed:
                ci_s = "(fixed)"
            elif not self.identifiable.get(name, True):
                ci_s = "not identifiable"
            elif ci is None:
                ci_s = "-"
            else:
                ci_s = f"[{ci[0]:.5g}, {ci[1]:.5g}]"
            lines.append(f"{name:<28} {value:>12.6g}  {ci_s:<28} {parameter_unit(name)}")
        return "\n".join(lines)


@dataclass(frozen=True)
class _Uncertainty:
    """Per free parameter: 95 % interval, standard error, identifiable, and why not."""

    ci95: dict[str, tuple[float, float] | None]
    stderr: dict[str, float | None]
    identifiable: dict[str, bool]
    reasons: dict[str, str]
    covariance: FloatArray  # over the free parameters, physical units


def build_result(
    prob: Problem,
    z: FloatArray,
    lm: LMState,
    reasons: dict[str, str],
    fixed: dict[str, float],
    closure: str | None,
    warnings: list[str],
    t_start: float,
) -> FitResult:
    """The :class:`FitResult` at the optimum ``z``: intervals from the Gauss-Newton
    covariance, identifiability with reasons, initial states and free-run RMS."""
    r, A, _g = prob.cached(z, True)
    assert A is not None
    unc = _uncertainty(prob, z, r, A, reasons)
    vals = prob.values_at(z)
    notes = {n: frozenset({ParameterNote.FIXED}) for n in vals if n in fixed}
    notes = {n: v for n, v in notes.items() if n not in unc.reasons}  # said otherwise
    if closure:
        notes["Kt"] = frozenset({ParameterNote.ASSUMED})
    _complete(unc, vals, fixed, closure)
    x0s: dict[str, tuple[float, float, float]] = {}
    nseg: dict[str, int] = {}
    for q, ps in enumerate(prob.segs):
        x0 = prob.x0_of(z, q)
        x0s[ps.seg.label] = (float(x0[0]), float(x0[1]), float(x0[2]))
        nseg[ps.seg.label] = ps.seg.n
    # Free-run RMS per signal in physical units.
    rms = {k: float(np.sqrt(np.mean(v**2))) for k, v in prob.raw_residuals(z).items()}
    return FitResult(
        model=prob.model_at(z),
        values=vals,
        ci95=unc.ci95,
        stderr=unc.stderr,
        covariance=unc.covariance,
        covariance_names=tuple(prob.free),
        identifiable=unc.identifiable,
        reasons=unc.reasons,
        notes=notes,
        cost=0.5 * float(r @ r),
        n_samples=int(sum(ps.seg.n for ps in prob.segs)),
        rms=rms,
        noise=dict(prob.noise),
        free=tuple(prob.free),
        fixed=dict(fixed),
        closure=closure,
        initial_states=x0s,
        nfev=lm.nfev,
        iterations=lm.it,
        converged=lm.converged,
        message=lm.message,
        elapsed_s=time.perf_counter() - t_start,
        fast_path=prob.fast,
        warnings=tuple(warnings),
        added_inertia={ps.seg.label: ps.dJ for ps in prob.segs if ps.dJ > 0},
        _fitted_segments=nseg,
    )


def _uncertainty(
    prob: Problem, z: FloatArray, r: FloatArray, A: FloatArray, reasons: Mapping[str, str]
) -> _Uncertainty:
    """Covariance of z (globals and nuisances), then the globals in physical units."""
    dof = max(r.size - prob.n_total, 1)
    s2 = float(r @ r) / dof
    # on the matrix scaled to unit diagonal: B and a friction torque are fitted in
    # absolute units, and on a 0.5 W motor (B ~ 1e-8) their columns dwarf the others by
    # 1e10, so a tolerance on the raw eigenvalues called well-determined directions null
    d = np.sqrt(np.clip(np.diag(A), 1e-300, None)) if A.size else np.ones(0)
    w, V = np.linalg.eigh(A / np.outer(d, d))
    wmax = float(w.max()) if w.size else 1.0
    tol = wmax * 1e-13
    inv_w = np.where(w > tol, 1.0 / np.maximum(w, tol), np.inf)
    cov_z = (V * np.where(np.isfinite(inv_w), inv_w, 0.0)) @ V.T / np.outer(d, d) * s2
    null_dirs = V[:, w <= tol]
    vals = prob.values_at(z)
    ng = prob.n_global
    dvdz = prob.dvalue_dz(z)
    # a parameter that ran off towards exp's range (a failed candidate's refit) has a
    # variance beyond a float: inf, judged below as unconstrained, never a warning
    with np.errstate(over="ignore", invalid="ignore"):
        cov = cov_z[:ng, :ng] * np.outer(dvdz, dvdz)
    unc = _Uncertainty({}, {}, {}, dict(reasons), cov)
    for j, info in enumerate(prob.info):
        name = info.name
        in_null = null_dirs.size and float(np.max(np.abs(null_dirs[j, :]))) > 1e-3
        sz = math.sqrt(max(cov_z[j, j], 0.0))
        rel = sz if info.log else sz / max(abs(vals[name]), 1e-300)
        if in_null or not math.isfinite(sz) or not math.isfinite(float(cov[j, j])):
            unc.identifiable[name] = False
            unc.reasons[name] = (
                "the data do not constrain it (singular information matrix)"
                if in_null or not math.isfinite(sz)
                else f"the fit ran off ({name} = {vals[name]:.3g}): no finite interval"
            )
            unc.ci95[name] = None
            unc.stderr[name] = None
            continue
        unc.stderr[name] = math.sqrt(max(cov[j, j], 0.0))
        if info.log:
            unc.ci95[name] = (
                math.exp(max(min(z[j] - 1.96 * sz, 700.0), -700.0)),
                math.exp(max(min(z[j] + 1.96 * sz, 700.0), -700.0)),
            )
        else:
            unc.ci95[name] = (vals[name] - 1.96 * sz, vals[name] + 1.96 * sz)
        if rel > 0.5:
            unc.identifiable[name] = False
            unc.reasons[name] = (
                f"the 95 % interval spans more than a factor {math.exp(1.96 * 0.5):.1f} "
                "(relative standard error above 50 %)"
            )
        else:
            unc.identifiable[name] = True
    return unc


def _complete(
    unc: _Uncertainty,
    vals: Mapping[str, float],
    fixed: Mapping[str, float],
    closure: str | None,
) -> None:
    """Entries for the parameters that were not free: tied, fixed or held."""
    if closure:
        unc.ci95["Kt"] = unc.ci95.get("Ke")
        unc.stderr["Kt"] = unc.stderr.get("Ke")
        unc.identifiable["Kt"] = unc.identifiable.get("Ke", True)
        unc.reasons["Kt"] = "assumed equal to Ke (closure Kt = Ke in SI units)"
    for name in vals:
        unc.ci95.setdefault(name, None)
        unc.stderr.setdefault(name, None)
        if name in fixed:
            unc.identifiable.setdefault(name, True)
            unc.reasons.setdefault(name, "fixed by the user")
        elif name not in unc.identifiable:
            unc.identifiable[name] = name not in unc.reasons
            unc.reasons.setdefault(name, "not fitted (held at its initial value)")
