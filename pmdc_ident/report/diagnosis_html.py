"""HTML page of a diagnosis: verdict, localization, candidates, regimes, traces.

Plots are matplotlib PNGs (Agg backend, no display needed) written next to
``index.html``.
"""

from __future__ import annotations

import html
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from pmdc_ident.core.diagnosis.results import DiagnosisResult  # noqa: E402
from pmdc_ident.core.safe_write import save_figure, write_text  # noqa: E402

__all__ = ["write_diagnosis_report"]

MAX_TRACE_SEGMENTS = 8


def _traces(result: DiagnosisResult, path: Path) -> bool:
    segs = result.held_out[:MAX_TRACE_SEGMENTS]
    if not segs or not result.predictions_before:
        return False
    fig, axes = plt.subplots(len(segs), 2, figsize=(12, 2.2 * len(segs)), squeeze=False)
    for row, seg in enumerate(segs):
        before = result.predictions_before[row]
        after = result.predictions_after[row]
        for col, (sig, unit) in enumerate((("current", "A"), ("speed", "rad/s"))):
            ax = axes[row][col]
            meas = seg.current if sig == "current" else seg.speed_or_derivative()
            if meas is None:
                ax.set_visible(False)
                continue
            mk = "o" if seg.n < 50 else None  # tables: show the samples
            ax.plot(seg.t, meas, color="0.6", lw=0.8, marker=mk, label="measured")
            ax.plot(seg.t, getattr(before, sig), color="tab:red", lw=1.0, label="linear model")
            ax.plot(
                seg.t,
                getattr(after, sig),
                color="tab:blue",
                lw=1.0,
                ls="--",
                label="augmented model",
            )
            ax.set_ylabel(f"{sig} ({unit})", fontsize=8)
            ax.set_title(seg.label, fontsize=8)
            ax.tick_params(labelsize=7)
    axes[0][0].legend(fontsize=7)
    axes[-1][0].set_xlabel("t (s)")
    axes[-1][1].set_xlabel("t (s)")
    fig.tight_layout()
    save_figure(fig, path, dpi=90)
    plt.close(fig)
    return True


def _localization(result: DiagnosisResult, path: Path) -> None:
    bds = [b for b in result.localization.breakdowns if b.items]
    fig, axes = plt.subplots(
        len(bds), 1, figsize=(9, 1.1 + 0.32 * sum(len(b.items) for b in bds)), squeeze=False
    )
    for ax, b in zip(axes[:, 0], bds, strict=True):
        labels = [it.label for it in b.items]
        y = np.arange(len(labels))
        ax.barh(y - 0.2, [it.share for it in b.items], 0.4, color="tab:red", label="share of gap")
        ax.barh(
            y + 0.2,
            [it.sample_share for it in b.items],
            0.4,
            color="0.7",
            label="share of samples",
        )
        ax.set_yticks(y, labels, fontsize=7)
        ax.set_xlim(0, 1)
        ax.set_title(b.category.replace("_", " "), fontsize=8, loc="left")
        ax.tick_params(labelsize=7)
    axes[0][0].legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    save_figure(fig, path, dpi=90)
    plt.close(fig)


def _candidates(result: DiagnosisResult, path: Path) -> None:
    cands = list(result.candidates)[:16]
    fig, ax = plt.subplots(figsize=(8, 0.8 + 0.3 * max(len(cands), 1)))
    if cands:
        labels = ["+".join(c.effects) for c in cands]
        y = np.arange(len(cands))
        colors = ["tab:blue" if c.significant else "0.7" for c in cands]
        ax.barh(y, [max(min(c.shrink, 1.0), -0.2) for c in cands], color=colors)
        ax.set_yticks(y, labels, fontsize=7)
        ax.invert_yaxis()
    ax.axvline(0.0, color="k", lw=0.5)
    ax.set_xlabel("held-out gap shrink (blue: beats the parameter penalty)", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=90)
    plt.close(fig)


def _regimes(result: DiagnosisResult, path: Path) -> None:
    regs = [r for r in result.regimes if r.category not in ("segment",)]
    fig, ax = plt.subplots(figsize=(9, 0.8 + 0.28 * max(len(regs), 1)))
    if regs:
        y = np.arange(len(regs))
        ax.barh(
            y - 0.2,
            [max(r.gap_before, 0) for r in regs],
            0.4,
            color="tab:red",
            label="linear model",
        )
        ax.barh(
            y + 0.2, [max(r.gap_after, 0) for r in regs], 0.4, color="tab:blue", label="augmented"
        )
        ax.set_yticks(y, [f"{r.category}: {r.label}" for r in regs], fontsize=6)
        ax.invert_yaxis()
        ax.legend(fontsize=7)
    ax.set_xlabel("held-out gap within the regime", fontsize=8)
    fig.tight_layout()
    save_figure(fig, path, dpi=90)
    plt.close(fig)


def _table(rows: list[list[str]], head: list[str]) -> str:
    h = "".join(f"<th>{html.escape(c)}</th>" for c in head)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows
    )
    return f"<table><tr>{h}</tr>{body}</table>"


def write_diagnosis_report(result: DiagnosisResult, out_dir: Path) -> Path:
    """Write ``index.html``, its PNGs and ``diagnosis.json`` into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    has_traces = _traces(result, out / "traces.png")
    _localization(result, out / "localization.png")
    _candidates(result, out / "candidates.png")
    _regimes(result, out / "regimes.png")
    write_text(out / "diagnosis.json", json.dumps(result.to_json(), indent=2) + "\n")
    v = result.verdict
    cand_rows = [
        [
            "+".join(c.effects),
            f"{c.gap:.4g}",
            f"{c.shrink:.1%}",
            str(c.added_parameters),
            "yes" if c.significant else "no",
            ", ".join(f"{k}={val:.4g}" for k, val in c.parameters.items()),
        ]
        for c in result.candidates
    ]
    par_rows = [
        [
            p.name,
            f"{p.value:.6g}",
            f"[{p.ci95[0]:.4g}, {p.ci95[1]:.4g}]" if p.ci95 else "-",
            "yes" if p.identifiable else "no",
        ]
        for p in result.augmented
    ]
    reg_rows = [
        [
            r.category,
            r.label,
            f"{r.sample_share:.0%}",
            f"{r.gap_before:.3g}",
            f"{r.gap_after:.3g}",
            f"{r.shrink:.0%}" if np.isfinite(r.shrink) else "-",
        ]
        for r in result.regimes
    ]
    ties = "".join(
        f"<li>{html.escape(' / '.join(t.effects))}: {html.escape(t.separating_test)}</li>"
        for t in v.ties
    )
    page = f"""<!doctype html>
<html><head><meta charset="utf-8"><title>pmdc-ident diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}
table{{border-collapse:collapse;font-size:12px}}td,th{{border:1px solid #ccc;padding:2px 6px}}
.v{{font-size:20px;font-weight:bold}}</style></head><body>
<h1>Sim-to-real gap diagnosis</h1>
<p class="v">verdict: {html.escape(v.status.value)}
{html.escape(("(" + ", ".join(v.effects) + ")") if v.effects else "")}</p>
<p>{html.escape(v.message)}</p>
{"<h3>Ties</h3><ul>" + ties + "</ul>" if ties else ""}
<pre>{html.escape(chr(10).join(result.summary_lines()))}</pre>
<h2>Split</h2><ul>{"".join(f"<li>{html.escape(d)}</li>" for d in result.split.description)}</ul>
<h2>Where the gap lies (linear model, held-out data)</h2>
<ul>{"".join(f"<li>{html.escape(s)}</li>" for s in result.localization.sentences)}</ul>
<img src="localization.png">
<h2>Candidates (fitted on the fit segments, scored held out)</h2>
<img src="candidates.png">
{
        _table(
            cand_rows,
            ["effects", "held-out gap", "shrink", "added params", "beats penalty", "parameters"],
        )
    }
<h2>How far it shrinks, per regime</h2>
<img src="regimes.png">
{_table(reg_rows, ["category", "regime", "samples", "gap before", "gap after", "shrink"])}
<h2>Augmented model parameters</h2>
{_table(par_rows, ["parameter", "value", "95 % interval", "identifiable"])}
<p>Assumptions: {html.escape("; ".join(result.assumptions))}</p>
{'<h2>Held-out traces</h2><img src="traces.png">' if has_traces else ""}
</body></html>
"""
    return write_text(out / "index.html", page)
