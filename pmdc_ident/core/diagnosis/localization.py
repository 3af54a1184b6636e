"""Where the gap lies: the held-out excess error broken down by signal and regime.

Every breakdown splits the held-out samples into labelled groups (a regime) and
reports, for each group, its *share* of the excess residual energy and its share
of the samples; a share well above the sample share says the gap concentrates
there. Regimes come from the measured data only (speed, direction, transients,
time into the run, sweep frequency, shaft angle), so they are the same for every
model and the gap per regime can be compared before and after an effect is
added.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment, TestKind
from pmdc_ident.core.diagnosis.scoring import Residuals

__all__ = [
    "Breakdown",
    "Localization",
    "RegimeItem",
    "angle_harmonics",
    "localize",
    "regime_masks",
    "shaft_angle",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

NEAR_ZERO_FRACTION = 0.05  # |w| below this fraction of the largest |w|
MAX_HARMONIC = 64
MIN_PROMINENCE = 10.0  # strongest harmonic over the median one, to call it periodic


@dataclass(frozen=True)
class RegimeItem:
    label: str
    share: float  # of the excess residual energy, 0..1
    sample_share: float  # of the held-out samples, 0..1
    gap: float  # the gap measure within this group

    def to_json(self) -> dict[str, object]:
        return {
            "label": self.label,
            "share": round(self.share, 4),
            "sample_share": round(self.sample_share, 4),
            "gap": self.gap,
        }


@dataclass(frozen=True)
class Breakdown:
    category: str
    items: tuple[RegimeItem, ...]

    def top(self) -> RegimeItem | None:
        return max(self.items, key=lambda it: it.share) if self.items else None


@dataclass(frozen=True)
class Localization:
    breakdowns: tuple[Breakdown, ...]
    sentences: tuple[str, ...]
    angle_periods_per_rev: int | None  # strongest shaft-angle harmonic
    angle_share: float  # share of the excess it explains
    angle_candidates: tuple[int, ...] = ()  # strongest N, however weak

    def to_json(self) -> dict[str, object]:
        out: dict[str, object] = {
            b.category: [it.to_json() for it in b.items] for b in self.breakdowns
        }
        out["shaft_angle"] = {
            "periods_per_rev": self.angle_periods_per_rev,
            "share": round(self.angle_share, 4),
        }
        out["summary"] = list(self.sentences)
        return out


# ---------------------------------------------------------------------------
def _sweep_frequency(seg: Segment) -> FloatArray | None:
    """Instantaneous command frequency (Hz) from zero crossings around the median."""
    if seg.voltage is None or seg.open_mask.any():
        return None
    v = seg.voltage - np.median(seg.voltage)
    s = np.signbit(v)
    cross = np.flatnonzero(s[1:] != s[:-1])
    if cross.size < 3:
        return None
    tc = seg.t[cross]
    half = np.diff(tc)
    f = 1.0 / (2.0 * half)
    tm = 0.5 * (tc[1:] + tc[:-1])
    return np.interp(seg.t, tm, f)


def shaft_angle(seg: Segment) -> FloatArray:
    """The measured shaft angle (the encoder's, else the integrated speed)."""
    if seg.position is not None:
        return seg.position
    w = seg.speed_or_derivative()
    dt = np.diff(seg.t)
    return np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * dt)])


def regime_masks(
    segments: Sequence[Segment], tau_m_s: float | None = None
) -> dict[str, dict[str, BoolArray]]:
    """Boolean sample masks per category and group, over the concatenated segments."""
    w = np.concatenate([s.speed_or_derivative() for s in segments])
    n = w.size
    wmax = float(np.max(np.abs(w))) or 1.0
    aw = np.abs(w) / wmax
    out: dict[str, dict[str, BoolArray]] = {}

    seg_idx = np.concatenate([np.full(s.n, k) for k, s in enumerate(segments)])
    out["segment"] = {s.label: seg_idx == k for k, s in enumerate(segments)}
    kinds = np.array([s.kind.value for s in segments])[seg_idx]
    out["test_type"] = {k: kinds == k for k in dict.fromkeys(kinds.tolist())}

    z = NEAR_ZERO_FRACTION
    out["speed_band"] = {
        f"near zero (|w| < {z:.0%} of max)": aw < z,
        "low (5-33 % of max)": (aw >= z) & (aw < 1 / 3),
        "mid (33-67 % of max)": (aw >= 1 / 3) & (aw < 2 / 3),
        "high (> 67 % of max)": aw >= 2 / 3,
    }
    out["direction"] = {
        "forward": w > z * wmax,
        "reverse": w < -z * wmax,
        "standstill": aw <= z,
    }

    # transients: measured acceleration above 5 % of the top speed per time constant
    acc = np.concatenate([np.gradient(s.speed_or_derivative(), s.t) for s in segments])
    k = max(1, int(round(n / 2000)))
    if k > 1:
        acc = np.convolve(acc, np.ones(2 * k + 1) / (2 * k + 1), mode="same")
    if tau_m_s is None or not math.isfinite(tau_m_s) or tau_m_s <= 0:
        thresh = float(np.percentile(np.abs(acc), 75))
    else:
        thresh = 0.05 * wmax / tau_m_s
    is_open = np.concatenate([s.open_mask for s in segments])
    transient = (np.abs(acc) > thresh) & ~is_open
    out["dynamics"] = {
        "transient": transient,
        "steady state": ~transient & ~is_open,
        "coasting (armature open)": is_open,
    }

    t = np.concatenate([s.t for s in segments])
    t0, t1 = float(t.min()), float(t.max())
    edges = np.linspace(t0, t1, 5)
    out["time_in_run"] = {
        f"{q + 1}. quarter ({edges[q]:.3g}-{edges[q + 1]:.3g} s)": (t >= edges[q])
        & ((t < edges[q + 1]) | (q == 3))
        for q in range(4)
    }

    freq = np.full(n, np.nan)
    start = 0
    for s in segments:
        if s.kind is TestKind.SWEEP:
            f = _sweep_frequency(s)
            if f is not None:
                freq[start : start + s.n] = f
        start += s.n
    ok = np.isfinite(freq)
    if ok.sum() > 10:
        lo, hi = float(np.nanmin(freq)), float(np.nanmax(freq))
        if hi > lo > 0:
            e = np.geomspace(lo, hi, 5)
            out["sweep_band"] = {
                f"{e[q]:.3g}-{e[q + 1]:.3g} Hz": ok
                & (freq >= e[q])
                & ((freq < e[q + 1]) | (q == 3))
                for q in range(4)
            }
    return out


def angle_harmonics(
    segments: Sequence[Segment], res: Residuals, max_harmonic: int = MAX_HARMONIC
) -> tuple[int | None, float, tuple[int, ...]]:
    """Strongest harmonic N of the shaft angle in the residuals and its energy share.

    Each signal's residual (relative to its scale) is regressed on sin/cos(N theta)
    for N = 1..max_harmonic; the share is the energy the best N explains over the
    total excess energy. Only samples while turning are used. Also returns the
    three strongest N (the starts of a cogging candidate), however weak.
    """
    theta = np.concatenate([shaft_angle(s) for s in segments])
    w = np.concatenate([s.speed_or_derivative() for s in segments])
    # cogging shows most where the rotor crawls through its detents: keep slow samples
    moving = np.abs(w) > 0.002 * (float(np.max(np.abs(w))) or 1.0)
    if moving.sum() < 50 or np.ptp(theta[moving]) < 4 * math.pi:
        return None, 0.0, ()
    total = _relative_excess(res)
    if total <= 0:
        return None, 0.0, ()
    ranked = harmonic_energies(theta[moving], res, moving, max_harmonic)
    best_n, best_e = ranked[0]
    share = min(best_e / total, 1.0)
    top = tuple(n for n, _ in ranked[:3])
    # periodic when one harmonic stands out of the others (noise spreads evenly)
    median_e = float(np.median([e for _, e in ranked])) or 1e-300
    periodic = best_e >= MIN_PROMINENCE * median_e
    return (best_n if periodic else None), share, top


def _relative_excess(res: Residuals) -> float:
    """Excess residual energy relative to each signal's scale (the units of
    :func:`harmonic_energies`: the weighting that finds a detent's count, where noise
    units would let a noisy speed's own harmonics drown it), averaged over signals."""
    parts = [
        float(np.nansum(np.maximum(err**2 - res.noise.sigma[sig] ** 2, 0.0)))
        / res.noise.scale[sig] ** 2
        for sig, err in res.error.items()
    ]
    return float(np.mean(parts)) if parts else 0.0


def harmonic_energies(
    th: FloatArray, res: Residuals, moving: NDArray[np.bool_], max_harmonic: int
) -> list[tuple[int, float]]:
    """(N, residual energy explained by sin/cos(N theta)), strongest first."""
    out: list[tuple[int, float]] = []
    for n_h in range(1, max_harmonic + 1):
        basis = np.column_stack([np.sin(n_h * th), np.cos(n_h * th)])
        energy = 0.0
        for sig, err in res.error.items():
            y = np.nan_to_num(err[moving]) / res.noise.scale[sig]
            y = y - _smooth(y)
            coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
            energy += float(np.sum((basis @ coef) ** 2))
        energy /= max(len(res.error), 1)
        out.append((n_h, energy))
    return sorted(out, key=lambda ne: -ne[1])


def _smooth(y: FloatArray, width: int = 201) -> FloatArray:
    """Moving average: removes slow residual trends before the angle regression."""
    if y.size <= width:
        return np.full_like(y, float(np.mean(y)))
    kernel = np.ones(width) / width
    return np.convolve(y, kernel, mode="same")


def breakdown(res: Residuals, masks: dict[str, BoolArray], category: str) -> Breakdown:
    e = res.excess_per_sample()
    n = e.size
    sums = {lab: max(float(np.sum(e[m])), 0.0) for lab, m in masks.items()}
    total = sum(sums.values()) or 1.0
    items = tuple(
        RegimeItem(
            label=lab,
            share=sums[lab] / total,
            sample_share=float(m.sum()) / n if n else 0.0,
            gap=float(np.mean(e[m])) if m.any() else 0.0,
        )
        for lab, m in masks.items()
        if m.any()
    )
    return Breakdown(category, items)


_CATEGORY_WORDS = {
    "signal": "signal",
    "segment": "segment",
    "test_type": "test type",
    "speed_band": "speed band",
    "direction": "direction",
    "dynamics": "regime",
    "time_in_run": "time into the run",
    "sweep_band": "sweep frequency band",
}


def localize(
    segments: Sequence[Segment],
    res: Residuals,
    masks: dict[str, dict[str, BoolArray]],
) -> Localization:
    """All breakdowns of the baseline's held-out residuals, with a sentence for each."""
    by_sig = res.gap_by_signal()
    pos = {k: max(v, 0.0) for k, v in by_sig.items()}
    tot = sum(pos.values()) or 1.0
    sig_items = tuple(RegimeItem(k, pos[k] / tot, 1.0, by_sig[k]) for k in by_sig)
    bds = [Breakdown("signal", sig_items)]
    bds += [breakdown(res, m, cat) for cat, m in masks.items()]
    n_h, share, strongest = angle_harmonics(segments, res)
    sentences: list[str] = []
    for b in bds:
        top = b.top()
        if top is None or top.share <= 0:
            continue
        word = _CATEGORY_WORDS.get(b.category, b.category)
        if b.category == "signal":
            sentences.append(f"by signal: {top.label} holds {top.share:.0%} of the excess error")
            continue
        ratio = top.share / top.sample_share if top.sample_share > 0 else float("inf")
        conc = f" ({ratio:.1f}x its share of samples)" if ratio >= 1.5 else " (spread evenly)"
        sentences.append(
            f"by {word}: {top.label} holds {top.share:.0%} of the gap in "
            f"{top.sample_share:.0%} of the samples{conc}"
        )
    if n_h is not None:
        sentences.append(
            f"by shaft angle: {share:.0%} of the gap is periodic in the shaft angle, "
            f"{n_h} periods per turn"
        )
    return Localization(tuple(bds), tuple(sentences), n_h, share, strongest)
