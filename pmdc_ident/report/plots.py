"""Report plots of an identification (matplotlib, Agg backend: no display needed).

* ``segment_<label>.png``: measured and simulated (free-run) current and speed
  of each dynamic segment, with the residuals underneath;
* ``frequency_response.png``: the sweep's non-parametric I/V and w/V with
  coherence, the identified model's response laid over them;
* ``classical.png``: the staircase lines (E against w, Kt*i against w) and the
  coast-down with its Coulomb + viscous fit;
* ``methods.png``: each method's estimates relative to the reported ones.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pmdc_ident.core.data import Segment  # noqa: E402
from pmdc_ident.core.estimators.classical import (  # noqa: E402
    coast_speed,
    steady_state_points,
)
from pmdc_ident.core.estimators.frequency import model_frequency_response  # noqa: E402
from pmdc_ident.core.identification.results import IdentificationResult  # noqa: E402
from pmdc_ident.core.safe_write import save_figure  # noqa: E402

__all__ = ["write_identify_report"]


def _safe(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label)[:60] or "segment"


def write_identify_report(
    result: IdentificationResult, segments: Sequence[Segment], outdir: str | Path
) -> list[Path]:
    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    if result.fit is not None:
        fitted = set(result.fit_info.get("segments", []))
        dyn = [s for s in segments if s.label in fitted]
        preds = result.fit.simulate_segments(dyn)
        for seg, pred in zip(dyn, preds, strict=True):
            written.append(_segment_plot(seg, pred, out, result.model_kind))
    if result.frequency is not None:
        written.append(_frequency_plot(result, out))
    if "classical" in result.methods:
        p = _classical_plot(result, segments, out)
        if p is not None:
            written.append(p)
    written.append(_methods_plot(result, out))
    return written


def _segment_plot(seg: Segment, pred, out: Path, kind: str) -> Path:
    rows = []
    if seg.current is not None and seg.voltage is not None:
        rows.append(("current", "A", seg.current, pred.current))
    if seg.speed is not None:
        rows.append(("speed", "rad/s", seg.speed, pred.speed))
    elif seg.position is not None:
        rows.append(("position", "rad", seg.position, pred.position))
    fig, axes = plt.subplots(2, len(rows), figsize=(6 * len(rows), 6), squeeze=False)
    t = seg.t - seg.t[0]
    for c, (name, unit, y, yhat) in enumerate(rows):
        ax = axes[0, c]
        ax.plot(t, y, lw=0.8, label="measured")
        ax.plot(t, yhat, lw=1.0, label=f"simulated ({kind})")
        ax.set_ylabel(f"{name} ({unit})")
        ax.set_title(f"{seg.label}: {name}")
        ax.legend(loc="best", fontsize=8)
        ax2 = axes[1, c]
        ax2.plot(t, y - yhat, lw=0.6, color="C3")
        rms = float(np.sqrt(np.mean((y - yhat) ** 2)))
        ax2.set_title(f"residual (rms {rms:.3g} {unit})", fontsize=9)
        ax2.set_xlabel("t (s)")
        ax2.set_ylabel(f"{unit}")
    fig.tight_layout()
    p = out / f"segment_{_safe(seg.label)}.png"
    save_figure(fig, p, dpi=90)
    plt.close(fig)
    return p


def _frequency_plot(result: IdentificationResult, out: Path) -> Path:
    fr = result.frequency
    model = model_frequency_response(result.model.params, fr.freq_hz, fr.dt_s)
    pairs = [("speed_per_voltage", fr.speed_per_voltage, fr.coherence_speed, "(rad/s)/V")]
    if fr.current_per_voltage is not None:
        pairs.insert(
            0, ("current_per_voltage", fr.current_per_voltage, fr.coherence_current, "A/V")
        )
    fig, axes = plt.subplots(3, len(pairs), figsize=(6 * len(pairs), 8), squeeze=False)
    for c, (key, h, coh, unit) in enumerate(pairs):
        ok = coh >= 0.9
        ax = axes[0, c]
        ax.loglog(fr.freq_hz, np.abs(h), ".", ms=3, color="0.6", label="data (all)")
        ax.loglog(fr.freq_hz[ok], np.abs(h[ok]), ".", ms=4, label="data (coherence >= 0.9)")
        ax.loglog(fr.freq_hz, np.abs(model[key]), lw=1.2, label="identified model")
        ax.set_ylabel(f"|{key}| ({unit})")
        ax.legend(fontsize=8)
        ax.set_title(key.replace("_", " "))
        ax = axes[1, c]
        ax.semilogx(fr.freq_hz, np.degrees(np.angle(h)), ".", ms=3, color="0.6")
        ax.semilogx(fr.freq_hz, np.degrees(np.angle(model[key])), lw=1.2)
        ax.set_ylabel("phase (deg)")
        ax = axes[2, c]
        ax.semilogx(fr.freq_hz, coh, lw=0.8)
        ax.axhline(0.9, ls="--", color="0.5")
        ax.set_ylim(0, 1.05)
        ax.set_ylabel("coherence")
        ax.set_xlabel("f (Hz)")
    fig.tight_layout()
    p = out / "frequency_response.png"
    save_figure(fig, p, dpi=90)
    plt.close(fig)
    return p


def _classical_plot(result: IdentificationResult, segments, out: Path) -> Path | None:
    info = result.methods["classical"]
    vals = info.get("values", {})
    try:
        pts = steady_state_points(segments)
    except Exception:  # noqa: BLE001 - a plot must never fail the command
        pts = []
    coasts = [s for s in segments if s.kind.value == "coast"]
    if not pts and not coasts:
        return None
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    if pts and "Ke" in vals:
        V = np.array([p.voltage_v for p in pts])
        i = np.array([p.current_a for p in pts])
        w = np.array([p.speed_rad_s for p in pts])
        R = vals.get("R", 0.0)
        axes[0].plot(w, V - R * i, "o", label="E = V - R i")
        ww = np.linspace(0, w.max() * 1.05, 50)
        axes[0].plot(ww, vals["Ke"] * ww, label=f"Ke = {vals['Ke']:.4g} V*s/rad")
        axes[0].set_xlabel("w (rad/s)")
        axes[0].set_ylabel("E (V)")
        axes[0].legend(fontsize=8)
        kt = vals.get("Kt", vals["Ke"])
        tc = vals.get("coulomb_friction.torque_nm", 0.0)
        b = vals.get("B", 0.0)
        axes[1].plot(w, kt * i, "o", label="Kt i")
        axes[1].plot(ww, tc + b * ww, label=f"Tc + B w: {tc:.3g} + {b:.3g} w")
        axes[1].plot(ww, b * ww, ":", label="viscous only")
        axes[1].set_xlabel("w (rad/s)")
        axes[1].set_ylabel("torque (N*m)")
        axes[1].legend(fontsize=8)
    if coasts and "coast" in info:
        seg = coasts[0]
        mask = seg.open_mask if seg.voltage is not None else np.ones(seg.n, bool)
        t = seg.t[mask] - seg.t[mask][0]
        w = seg.speed_or_derivative()[mask]
        c = info["coast"]
        J = c["J"]
        tc = vals.get("coulomb_friction.torque_nm", 0.0)
        b = vals.get("B", 0.0)
        tt = np.linspace(0, t[-1], 200)
        axes[2].plot(t, w, "o", label="measured")
        axes[2].plot(tt, coast_speed(tt, w[0], b / J, tc / J), label=f"Coulomb+viscous, J={J:.3g}")
        axes[2].set_xlabel("t (s)")
        axes[2].set_ylabel("w (rad/s)")
        axes[2].legend(fontsize=8)
    fig.tight_layout()
    p = out / "classical.png"
    save_figure(fig, p, dpi=90)
    plt.close(fig)
    return p


def _methods_plot(result: IdentificationResult, out: Path) -> Path:
    names = [n for n in ("R", "L", "Ke", "Kt", "J", "B", "coulomb_friction.torque_nm")]
    methods = [m for m, v in result.methods.items() if v.get("values")]
    fig, ax = plt.subplots(figsize=(9, 4))
    width = 0.8 / max(len(methods), 1)
    for k, m in enumerate(methods):
        ratios = []
        for n in names:
            ref = result.parameters.get(n)
            v = result.methods[m]["values"].get(n)
            ok = ref is not None and v is not None and ref.value != 0
            ratios.append(v / ref.value if ok else np.nan)
        ax.bar(np.arange(len(names)) + k * width, ratios, width, label=m)
    ax.axhline(1.0, color="0.3", lw=0.8)
    ax.set_xticks(np.arange(len(names)) + 0.4 - width / 2)
    ax.set_xticklabels([n.replace("coulomb_friction.torque_nm", "Tc") for n in names])
    ax.set_ylabel("estimate / reported value")
    ax.set_ylim(0, 2)
    ax.legend(fontsize=8)
    fig.tight_layout()
    p = out / "methods.png"
    save_figure(fig, p, dpi=90)
    plt.close(fig)
    return p
