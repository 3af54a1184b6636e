"""The diagnosis' noise levels: the data-quality gate's estimator, also where the
signal changes within a sample (a 50 Hz log of a fast motor)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.motor_records import Motor, prbs, simulate

from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis import VerdictStatus, diagnose
from pmdc_ident.core.diagnosis.scoring import estimate_noise
from pmdc_ident.core.quality.information import _noise as gate_noise

TRUE_NOISE_A = 0.003


@pytest.fixture(scope="module")
def prbs_50hz_quantised() -> Segment:
    # benchmarks/bench_record_shapes.py's 50 Hz PRBS record: the current settles in
    # 0.25 ms and the speed in 2 ms, both within one 20 ms sample; the speed sensor
    # gives 12 counts per turn per sample
    m = Motor(R=8.0, L=2e-3, Ke=0.008, Kt=0.008, J=2e-7, B=1e-8, Tc=2e-5)
    rec = simulate(m, prbs(1000, 6.0, 1, seed=3), 50, substeps=100, noise_current=TRUE_NOISE_A)
    q = 2 * math.pi / 12 / 0.02
    speed = np.round(rec.speed / q) * q
    return Segment("prbs", rec.t, rec.voltage, current=rec.current, speed=speed)


def test_a_signal_that_settles_within_a_sample_is_not_taken_for_noise(prbs_50hz_quantised):
    seg = prbs_50hz_quantised
    noise = estimate_noise([seg])
    # second differences alone read 0.42 A here (the PRBS itself); the one-step ARX
    # residual sees the 3 mA of the sensor
    assert noise.sigma["current"] == pytest.approx(TRUE_NOISE_A, rel=0.6)
    q = 2 * math.pi / 12 / 0.02
    assert noise.sigma["speed"] >= q / math.sqrt(12.0) * 0.999  # never below the quantum
    # one estimator: the gate reads the same levels
    assert gate_noise([seg])["current"] == pytest.approx(noise.sigma["current"], rel=1e-9)


def test_the_prbs_record_matches_the_linear_model_to_the_noise(prbs_50hz_quantised):
    r = diagnose([prbs_50hz_quantised])
    h = r.to_json()["holdout"]
    assert r.verdict.status is VerdictStatus.NO_GAP
    assert 0.0 <= h["gap_before"] < 1.0  # in noise variances, not a negative gap
    assert h["rms_error_before"]["current"] < 2.0 * TRUE_NOISE_A


def test_a_speed_differentiated_from_encoder_counts_has_their_noise():
    # a shaft turning at 40 rad/s, 52 counts per turn, 2 kHz: the central difference of
    # the counts has the rounding noise q / (dt sqrt(24)), which the diagnosis must
    # not read as a model gap (the generic floor of its own levels is sqrt(2) lower)
    rate, q = 2000.0, 2 * math.pi / 52
    t = np.arange(4000) / rate
    w = 40.0 + 5.0 * np.sin(2 * np.pi * 0.5 * t)
    theta = np.cumsum(w) / rate
    seg = Segment(
        "run",
        t,
        np.full(t.size, 6.0),
        current=np.full(t.size, 0.2) + 0.001 * np.sin(t),
        position=np.floor(theta / q) * q,
    )
    expected = q * rate / math.sqrt(24.0)
    got = estimate_noise([seg]).sigma["speed"]
    rounding = np.gradient(seg.position, t) - w
    # at a sixth of a count per sample the rounding is no white noise (its sd is
    # q/(2 dt) sqrt(p (1 - p)), p the share of differences that see a count): the
    # floor holds the estimate at least at the white-noise value and never above it
    assert expected * 0.99 <= got <= float(np.std(rounding)) * 1.05
