"""The benchmark's report: tables as text (markdown) and figures (matplotlib, Agg)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pmdc_ident.benchmark.scoring import VISIBLE, Score
from pmdc_ident.core.safe_write import save_figure

__all__ = [
    "confusion_text",
    "detail_text",
    "side_by_side",
    "summary_table",
    "truth_table_text",
    "write_figures",
]


def _pct(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.0%}"


def summary_table(sc: Score) -> str:
    fa, n_clean = sc.false_attribution
    oov = sc.oov_verdicts
    n_oov = sum(oov.values())
    oov_u, n_oov_vis = sc.oov_unexplained
    both, one, n_comp = sc.compounds
    vis, hid = sc.visible, sc.hidden
    lines = [
        "| effect | top-1 | tie-honest | visible runs | below noise | detection limit |",
        "|---|---:|---:|---:|---:|---|",
    ]
    limits = {lim.name: lim for lim in sc.limits()}
    for name, (t1, th, n, h) in sc.per_effect().items():
        lim = limits[name].text() if name in limits else "-"
        lines.append(
            f"| {name} | {_pct(t1 / n if n else math.nan)} | {_pct(th / n if n else math.nan)} "
            f"| {n} | {h} | {lim} |"
        )
    lines += [
        f"| **all visible effect runs** | **{_pct(sc.top1())}** | **{_pct(sc.tie_honest())}** "
        f"| {len(vis)} | {len(hid)} | |",
        f"| all effect runs (visible or not) | {_pct(sc.top1(sc.effect_runs))} | "
        f"{_pct(sc.tie_honest(sc.effect_runs))} | {len(sc.effect_runs)} | | |",
        "",
        "| check | result | runs |",
        "|---|---:|---:|",
        f"| effect-free runs: false attribution | {fa} ({_pct(fa / n_clean if n_clean else math.nan)}) | {n_clean} |",  # noqa: E501
        f"| out-of-vocabulary runs -> unexplained, visible runs | {_pct(oov_u / n_oov_vis if n_oov_vis else math.nan)} | {n_oov_vis} |",  # noqa: E501
        f"| out-of-vocabulary runs below the noise (not scored) | {n_oov - n_oov_vis} | |",
        f"| out-of-vocabulary runs -> unexplained, all runs | {_pct(oov['unexplained'] / n_oov if n_oov else math.nan)} | {n_oov} |",  # noqa: E501
        f"| out-of-vocabulary runs -> an effect named | {_pct(oov['explained'] / n_oov if n_oov else math.nan)} | {n_oov} |",  # noqa: E501
        f"| out-of-vocabulary runs -> no_gap | {_pct(oov['no_gap'] / n_oov if n_oov else math.nan)} | {n_oov} |",  # noqa: E501
        f"| median held-out shrink where the name is right | {_pct(sc.median_shrink_right)} | |",
        f"| two effects: both named (or tied) | {_pct(both / n_comp if n_comp else math.nan)} | {n_comp} |",  # noqa: E501
        f"| two effects: first named is one of them | {_pct(one / n_comp if n_comp else math.nan)} | {n_comp} |",  # noqa: E501
    ]
    secs = sc.seconds
    if secs:
        lines.append(
            f"| diagnose wall time per run (median / max) | {np.median(secs):.1f} s / "
            f"{max(secs):.1f} s | {len(secs)} |"
        )
    for key, what in (("cpu_s", "diagnose"), ("generate_cpu_s", "simulate")):
        cpu = [float(o.extra[key]) for o in sc.outcomes if key in o.extra]
        if cpu:
            lines.append(
                f"| {what} CPU per run (median / max) | {np.median(cpu):.2f} s / "
                f"{max(cpu):.1f} s | {len(cpu)} |"
            )
    errors = sum(1 for o in sc.outcomes if o.status == "error")
    if errors:
        lines.append(f"| runs the diagnosis failed on (error) | {errors} | |")
    lines.append("")
    lines.append(
        f"Visible: the effect moves the logged current or speed by >= {VISIBLE:g} noise "
        "RMS; tie-honest: right, or tied with the truth and the separating test named."
    )
    return "\n".join(lines)


def _limits(sc: Score) -> dict[str, str]:
    return {lim.name: lim.text() for lim in sc.limits()}


def side_by_side(scores: dict[str, Score]) -> str:
    """The plants' headline figures and per-effect results in one table (one column
    pair per plant)."""
    names = list(scores)
    head = "| | " + " | ".join(names) + " |"
    rule = "|---|" + "---:|" * len(names)

    def row(label: str, cells: list[str]) -> str:
        return f"| {label} | " + " | ".join(cells) + " |"

    def frac(ok: int, n: int) -> str:
        return f"{_pct(ok / n if n else math.nan)} ({ok} of {n})"

    lines = [head, rule]
    lines.append(row("tie-honest top-1, visible effect runs", [
        frac(sum(1 for o in sc.visible if _right(o)), len(sc.visible)) for sc in scores.values()
    ]))  # fmt: skip
    lines.append(row("top-1 (no ties counted)", [_pct(sc.top1()) for sc in scores.values()]))
    lines.append(row("effect runs below the noise (not scored)", [
        str(len(sc.hidden)) for sc in scores.values()
    ]))  # fmt: skip
    lines.append(row("false attributions, effect-free runs", [
        f"{sc.false_attribution[0]} of {sc.false_attribution[1]}" for sc in scores.values()
    ]))  # fmt: skip
    lines.append(row("out-of-vocabulary runs -> unexplained, visible runs", [
        frac(*sc.oov_unexplained) for sc in scores.values()
    ]))  # fmt: skip
    lines.append(row("out-of-vocabulary runs below the noise (not scored)", [
        str(len(sc.of_kind("oov")) - len(sc.oov_visible)) for sc in scores.values()
    ]))  # fmt: skip
    lines.append(row("out-of-vocabulary runs -> unexplained, all runs", [
        frac(sc.oov_verdicts["unexplained"], sum(sc.oov_verdicts.values()))
        for sc in scores.values()
    ]))  # fmt: skip
    lines.append(row("median held-out shrink where the name is right", [
        _pct(sc.median_shrink_right) for sc in scores.values()
    ]))  # fmt: skip
    both, one, n_comp = zip(*(sc.compounds for sc in scores.values()), strict=True)
    lines.append(row("two effects: both named (or tied)", [
        frac(b, n) for b, n in zip(both, n_comp, strict=True)
    ]))  # fmt: skip
    for key, what in (("generate_cpu_s", "simulate"), ("cpu_s", "diagnose")):
        cells = []
        for sc in scores.values():
            cpu = [float(o.extra[key]) for o in sc.outcomes if key in o.extra]
            cells.append(f"{np.median(cpu):.2f} s" if cpu else "-")
        lines.append(row(f"{what} CPU per run (median)", cells))
    lines += ["", "| effect | " + " | ".join(f"{n}: tie-honest (visible) | {n}: detection limit"
                                            for n in names) + " |",
              "|---|" + "---:|---|" * len(names)]  # fmt: skip
    effects: list[str] = []
    for sc in scores.values():
        effects += [e for e in sc.per_effect() if e not in effects]
    for e in effects:
        cells = []
        for sc in scores.values():
            per = sc.per_effect().get(e)
            if per is None:
                cells += ["-", "-"]
                continue
            _, th, n, _ = per
            cells += [f"{_pct(th / n if n else math.nan)} ({n})", _limits(sc).get(e, "-")]
        lines.append(f"| {e} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _right(o) -> bool:  # type: ignore[no-untyped-def]
    from pmdc_ident.benchmark.scoring import right_tie_honest

    return right_tie_honest(o)


def truth_table_text() -> str:
    """The MuJoCo plant's truth table (docs/mujoco.md prints the same)."""
    from pmdc_ident.benchmark.mujoco_truth import TRUTH_TABLE

    lines = [
        "| effect | equation | simulated by | model | right name | why |",
        "|---|---|---|---|---|---|",
    ]
    for r in TRUTH_TABLE:
        lines.append(
            f"| {r.name} | {r.equation} | {r.where} | {r.mechanism} | `{r.right}` | {r.why} |"
        )
    return "\n".join(lines)


def confusion_text(sc: Score) -> str:
    rows = sc.confusion()
    cols = sorted({c for r in rows.values() for c in r})
    width = 9
    head = "truth \\ named".ljust(22) + "".join(c[:width].rjust(width + 1) for c in cols)
    out = [head]
    for truth, row in rows.items():
        out.append(truth[:22].ljust(22) + "".join(str(row.get(c, 0) or ".").rjust(width + 1)
                                                  for c in cols))  # fmt: skip
    return "\n".join(out)


def detail_text(sc: Score) -> str:
    out = ["| effect | equation | tie-honest | runs |", "|---|---|---:|---:|"]
    for (name, eq), (ok, n) in sc.per_equation().items():
        out.append(f"| {name} | {eq} | {_pct(ok / n)} | {n} |")
    out += ["", "| effect | size | named (tie-honest) / runs |", "|---|---|---|"]
    for lim in sc.limits():
        cells = ", ".join(f"{s:g}: {ok}/{n}" for s, ok, n in lim.by_level)
        out.append(f"| {lim.name} | {lim.unit} | {cells} |")
    return "\n".join(out)


def write_figures(sc: Score, directory: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory.mkdir(parents=True, exist_ok=True)
    rows = sc.confusion()
    cols = sorted({c for r in rows.values() for c in r})
    mat = np.array([[rows[r].get(c, 0) for c in cols] for r in rows], dtype=float)
    fig, ax = plt.subplots(figsize=(1.0 + 0.55 * len(cols), 1.0 + 0.45 * len(rows)))
    frac = mat / np.maximum(mat.sum(axis=1, keepdims=True), 1)
    ax.imshow(frac, cmap="Blues", vmin=0, vmax=1, aspect="auto")
    for (i, j), v in np.ndenumerate(mat):
        if v:
            ax.text(j, i, f"{int(v)}", ha="center", va="center", fontsize=8)
    ax.set_xticks(range(len(cols)), cols, rotation=60, ha="right", fontsize=8)
    ax.set_yticks(range(len(rows)), list(rows), fontsize=8)
    ax.set_xlabel("named by the diagnosis (first effect; '(tie)' = truth in a named tie)")
    ax.set_ylabel("truth")
    ax.set_title("Confusion (visible effect runs, effect-free, out-of-vocabulary)")
    fig.tight_layout()
    p1 = directory / "confusion.png"
    save_figure(fig, p1, dpi=110)
    plt.close(fig)

    lims = sc.limits()
    fig, axes = plt.subplots(
        int(math.ceil(len(lims) / 4)) or 1, 4, figsize=(13, 2.6 * math.ceil(len(lims) / 4))
    )
    for ax, lim in zip(np.ravel(axes), lims, strict=False):
        sizes = [s for s, _, n in lim.by_level if n]
        rates = [ok / n for _, ok, n in lim.by_level if n]
        ax.plot(sizes, rates, "o-")
        ax.axhline(0.9, color="grey", lw=0.8, ls="--")
        if lim.limit is not None:
            ax.axvline(lim.limit, color="green", lw=0.8)
        ax.set_xscale("log")
        ax.set_ylim(-0.05, 1.05)
        ax.set_title(f"{lim.name}\nlimit {lim.text()}", fontsize=8)
        ax.set_xlabel(lim.unit, fontsize=8)
    for ax in np.ravel(axes)[len(lims) :]:
        ax.axis("off")
    fig.tight_layout()
    p2 = directory / "detection_limits.png"
    save_figure(fig, p2, dpi=110)
    plt.close(fig)
    return [p1, p2]
