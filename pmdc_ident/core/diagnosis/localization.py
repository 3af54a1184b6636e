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
from pmdc_ident.core.quantisation import quantum

__all__ = [
    "Breakdown",
    "Localization",
    "RegimeItem",
    "angle_harmonics",
    "localize",
    "prominence_needed",
    "regime_masks",
    "resolved_counts",
    "resolved_steps",
    "shaft_angle",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

NEAR_ZERO_FRACTION = 0.05  # |w| below this fraction of the largest |w|
MAX_HARMONIC = 64
MIN_PROMINENCE = 10.0  # strongest harmonic over the median one, to call it periodic
NYQUIST_PHASE_RAD = math.pi  # a period is resolved where its phase moves less per sample
# the chance that noise alone passes MIN_PROMINENCE over MAX_HARMONIC counts (each
# count's energy exponential: P(one > x median) = 2**-x); a wider search keeps it
FALSE_ALARM = MAX_HARMONIC * 2.0**-MIN_PROMINENCE  # 1/16 per record
MAX_COUNT = 1000.0  # periods per turn searched at most (the cogging effect's range)
# edges of the wide search; below 8 per turn the integers only: a geared motor shows
# poles (>= 2) x ratio (>= 4) per output turn, and slow residual trends over a few
# turns put non-integer peaks there on effect-free records (1.8 per turn)
WIDE_BANDS = (8.0, 64.0, 128.0, 256.0, 512.0, MAX_COUNT)
BINS_PER_PERIOD = 8  # angle grid of the wide search: phase error <= pi/8 at a band's top
OVERSAMPLE = 2  # counts per resolution step (1 / turns spanned) of the wide search
MAX_GRID = 2**22  # angle bins per band and signal at most (memory: 32 MB)
MIN_SAMPLES = 50
PEAKS_PER_BAND = 3  # a band's strongest peaks offered (a crawl's own time pattern is one)
MAX_WIDE = 6  # wide-search counts offered at most, the most prominent first
MEDIAN_FLOOR = 1e-5  # of a band's residual energy: its median no lower (leakage, not noise)


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
    angle_periods_per_rev: float | None  # strongest shaft-angle period count per turn
    angle_share: float  # share of the excess it explains
    angle_candidates: tuple[float, ...] = ()  # strongest N, however weak

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


def resolved_steps(theta: FloatArray, periods: float) -> NDArray[np.bool_]:
    """Per sample, whether a torque of ``periods`` per turn of the angle ``theta`` is
    resolved there: its phase moves less than half a period (pi) to the next sample."""
    return resolved_counts(theta) > periods


def resolved_counts(theta: FloatArray) -> FloatArray:
    """Per sample, the count per turn below which :func:`resolved_steps` holds there
    (pi over the angle step to the next sample; infinite at rest, 0 where unknown)."""
    step = np.diff(theta, append=theta[-1] + (theta[-1] - theta[-2] if theta.size > 1 else 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = NYQUIST_PHASE_RAD / np.abs(step)
    return np.nan_to_num(out, nan=0.0, posinf=np.inf)


def prominence_needed(counts: float) -> float:
    """The peak-over-median ratio a spectrum of ``counts`` independent period counts
    needs to call its peak periodic: noise alone passes it with ``FALSE_ALARM``
    (an extreme-value bound: each count's energy is exponential, so P(the largest of K
    exceeds x medians) ~ K 2**-x). ``MIN_PROMINENCE`` at ``MAX_HARMONIC`` counts."""
    return math.log2(max(counts, 1.0) / FALSE_ALARM)


def angle_harmonics(
    segments: Sequence[Segment], res: Residuals, max_harmonic: int = MAX_HARMONIC
) -> tuple[float | None, float, tuple[float, ...]]:
    """Strongest period count N of the shaft angle in the residuals and its energy share.

    Each signal's residual (relative to its scale) is regressed on sin/cos(N theta)
    for N = 1..max_harmonic; the share is the energy the best N explains over the
    total excess energy. Only samples while turning are used. Also returns the
    three strongest N (the starts of a cogging candidate), however weak.

    A geared motor with its encoder on the output repeats its cogging per *motor* turn:
    poles x gear ratio periods per output turn, neither an integer nor below 64 (a
    scooter hub's 12 x 9.78 = 117.36). :func:`wide_peaks` searches every count the
    record resolves (a grid of 1 / turns spanned, up to where the sampling aliases
    it, by the sampling or by the encoder's own steps); its peaks lead the candidates
    where they stand out of that wider spectrum by the extreme-value bound of the
    counts tried (:func:`prominence_needed`) and are not integers already tried.
    """
    thetas = [shaft_angle(s) for s in segments]
    theta = np.concatenate(thetas)
    w = np.concatenate([s.speed_or_derivative() for s in segments])
    # cogging shows most where the rotor crawls through its detents: keep slow samples
    moving = np.abs(w) > 0.002 * (float(np.max(np.abs(w))) or 1.0)
    total = _relative_excess(res)
    if total <= 0:
        return None, 0.0, ()
    best: float | None = None
    share = 0.0
    top: tuple[float, ...] = ()
    if moving.sum() >= MIN_SAMPLES and np.ptp(theta[moving]) >= 4 * math.pi:
        ranked = harmonic_energies(theta[moving], res, moving, max_harmonic)
        best_n, best_e = ranked[0]
        share = min(best_e / total, 1.0)
        top = tuple(float(n) for n, _ in ranked[:3])
        # periodic when one harmonic stands out of the others (noise spreads evenly)
        median_e = float(np.median([e for _, e in ranked])) or 1e-300
        if best_e >= MIN_PROMINENCE * median_e:
            best = float(best_n)
    counts = np.concatenate([resolved_counts(t) for t in thetas])
    wide = wide_peaks(theta, res, moving, counts, _encoder_top(segments), max_harmonic, best)
    if not wide:
        return best, share, top
    n_w, e_w = wide[0]
    if best is not None:
        # a periodic integer stands as before where it is the stronger, in noise units
        # (the wide search's: a coarse encoder's speed weighs no more than its noise)
        th, ys = theta[moving], _angle_signals(res, moving, noise_units=True)
        sel_w = moving & (counts > n_w)
        e_int = _count_energy(th, ys, best) / max(int(moving.sum()), 1)
        e_wide = _count_energy(
            theta[sel_w], _angle_signals(res, sel_w, noise_units=True), n_w
        ) / max(int(sel_w.sum()), 1)
        if e_int >= e_wide:
            return best, share, top
    return n_w, min(e_w / total, 1.0), (*(n for n, _ in wide), *top)


def _encoder_top(segments: Sequence[Segment]) -> float:
    """The largest count per turn the angle itself resolves: an encoder reads the angle
    in steps of its quantum q, and sin/cos(N theta) on that grid alias beyond half its
    counts per turn (pi / q; at its counts per turn they are constant, where any
    residual's mean shows as a peak). ``MAX_COUNT`` for an angle not quantised."""
    pos = [s.position for s in segments if s.position is not None]
    q = quantum(np.concatenate(pos)) if pos else None
    return MAX_COUNT if q is None else min(MAX_COUNT, NYQUIST_PHASE_RAD / q.step)


def wide_peaks(
    theta: FloatArray,
    res: Residuals,
    moving: NDArray[np.bool_],
    counts: FloatArray,
    top_count: float = MAX_COUNT,
    max_harmonic: int = MAX_HARMONIC,
    found_count: float | None = None,
) -> list[tuple[float, float]]:
    """Period counts (any real number per turn below ``top_count``) that stand out of
    the residuals' angle spectrum by :func:`prominence_needed` of every count tried, and
    their residual energy, the most prominent first (``PEAKS_PER_BAND`` per band, at
    most ``MAX_WIDE``; the fit side chooses among them, see
    :func:`~pmdc_ident.core.diagnosis.cogging.angle_cogging`); an integer
    up to ``max_harmonic`` is left out (the integer search has it).

    The counts are searched in bands (``WIDE_BANDS``), each on the moving samples that
    resolve the band's top count (``counts``, :func:`resolved_counts`: a sample moving
    half a period or more to the next aliases it), where those span at least two
    periods of its lowest count. A band's spectrum is the residual's Fourier transform
    over the angle (samples gridded at ``BINS_PER_PERIOD`` bins per period of its top
    count, one FFT), ``OVERSAMPLE`` counts per resolution step: 1 / turns spanned. The
    independent counts tried are the bands' widths times their turns spanned. A peak
    is refined by least squares on sin/cos(N theta) within one step.

    The spectrum is in noise units (each signal's residual over its noise, summed: as
    the output-error fit weighs them): in scale units a coarse encoder's differentiated
    speed, its quantisation a pattern in time at each crawl's constant speed, put lines
    (80.9, 118.6, 199.5 per turn at 480 counts per turn) above a true 97.3 seen in the
    current. A count the integer search found periodic (``found_count``) is removed
    first, and a band's median is floored at ``MEDIAN_FLOOR`` of its residual energy: a
    strong count's leakage is no peak of its own (an exact 6 per turn, nothing else, put
    one at 87.5 against a median of its own sidelobes)."""
    found: list[tuple[float, float, NDArray[np.bool_], float]] = []  # ratio, N, samples, turns
    tried = 0.0
    for lo, edge in zip(WIDE_BANDS[:-1], WIDE_BANDS[1:], strict=True):
        hi = min(edge, top_count)
        sel = moving & (counts > hi)
        if hi <= lo or sel.sum() < MIN_SAMPLES:
            continue
        th = theta[sel]
        span = float(np.ptp(th))
        turns = span / (2.0 * math.pi)
        if lo * turns < 2.0:
            continue
        d_th = 2.0 * math.pi / (hi * BINS_PER_PERIOD)
        size = 1 << int(math.ceil(math.log2(OVERSAMPLE * (span / d_th + 1.0))))
        if size > MAX_GRID:
            continue
        idx = np.rint((th - float(th.min())) / d_th).astype(np.int64)
        n_k = np.arange(size // 2 + 1) * (2.0 * math.pi / (size * d_th))
        band = (n_k > lo) & (n_k < hi)
        if band.sum() < 8:
            continue
        energy = np.zeros(int(band.sum()))
        raw = _angle_signals(res, sel, noise_units=True)
        floor = MEDIAN_FLOOR * float(np.mean([np.sum(y**2) for y in raw]))
        for y in _angle_signals(res, sel, found_count, th, noise_units=True):
            f = np.fft.rfft(np.bincount(idx, weights=y, minlength=size)[:size])
            energy += 2.0 * np.abs(f[band]) ** 2 / y.size
        energy /= max(len(res.error), 1)
        tried += (hi - lo) * turns
        median_e = max(float(np.median(energy)), floor, 1e-300)
        counts_b = n_k[band]
        for k in _peaks(energy, PEAKS_PER_BAND, 2 * OVERSAMPLE):
            found.append((float(energy[k]) / median_e, float(counts_b[k]), sel, turns))
    need = prominence_needed(tried)
    out: list[tuple[float, float]] = []
    for ratio, n0, sel, turns in sorted(found, key=lambda f: -f[0]):
        if ratio < need or len(out) >= MAX_WIDE:
            break
        th = theta[sel]
        ys = _angle_signals(res, sel, found_count, th, noise_units=True)
        step = 1.0 / (OVERSAMPLE * turns)
        grid = [float(n) for n in n0 + np.linspace(-step, step, 17) if 0 < n < top_count]
        if not grid:
            continue
        n_best = max(grid, key=lambda n: _count_energy(th, ys, n))
        near = round(n_best)
        if near <= max_harmonic and abs(n_best - near) < 1.0 / turns:
            continue  # an integer the integer search tried
        out.append((n_best, _count_energy(th, _angle_signals(res, sel, found_count, th), n_best)))
    return out


def _peaks(energy: FloatArray, count: int, apart: int) -> list[int]:
    """Indices of the ``count`` largest local maxima of ``energy``, ``apart`` bins or
    more from a larger one."""
    inner = np.flatnonzero(
        (energy >= np.r_[-np.inf, energy[:-1]]) & (energy >= np.r_[energy[1:], -np.inf])
    )
    out: list[int] = []
    for k in inner[np.argsort(-energy[inner])]:
        if all(abs(int(k) - j) >= apart for j in out):
            out.append(int(k))
        if len(out) >= count:
            break
    return out


def _angle_signals(
    res: Residuals,
    sel: NDArray[np.bool_],
    known: float | None = None,
    theta: FloatArray | None = None,
    *,
    noise_units: bool = False,
) -> list[FloatArray]:
    """Each signal's residual on the samples ``sel``, relative to its scale (its noise
    with ``noise_units``), its slow trend removed (:func:`_smooth`), and its part in
    sin/cos(``known`` theta) where given (``theta``: the angle on the samples ``sel``)."""
    out = []
    for sig, err in res.error.items():
        unit = res.noise.sigma[sig] if noise_units else res.noise.scale[sig]
        y = np.nan_to_num(err[sel]) / unit
        y = y - _smooth(y)
        if known is not None and theta is not None:
            basis = np.column_stack([np.sin(known * theta), np.cos(known * theta)])
            coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
            y = y - basis @ coef
        out.append(y)
    return out


def _count_energy(th: FloatArray, ys: Sequence[FloatArray], n: float) -> float:
    """Residual energy explained by sin/cos(n theta), averaged over the signals."""
    basis = np.column_stack([np.sin(n * th), np.cos(n * th)])
    energy = 0.0
    for y in ys:
        coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
        energy += float(np.sum((basis @ coef) ** 2))
    return energy / max(len(ys), 1)


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
    ys = _angle_signals(res, moving)
    out = [(n_h, _count_energy(th, ys, n_h)) for n_h in range(1, max_harmonic + 1)]
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
            f"{n_h:.6g} periods per turn"
        )
    return Localization(tuple(bds), tuple(sentences), n_h, share, strongest)
