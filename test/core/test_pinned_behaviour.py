"""The simulated backend's telemetry and the drift monitor's estimates on one short
scripted run, pinned to numbers.

Issue 26's refactoring (the effect registry, named kernel slots) was checked
"behaviour unchanged" by benchmarks/compare_behaviour.py on identify, diagnose and the
benchmark only; the plant behind the simulated driver (open armature, stiction, heating
with flux loss, delay, brush drop) and the drift estimator were in no comparison. The
numbers below were recorded on f02d77e, before the registry, and are the same on
5379a58 (after it): a change to either path now shows here, and must say why.
"""

from __future__ import annotations

import numpy as np
import pytest

from pmdc_ident.backends.sim import SimBackend
from pmdc_ident.core.effects import BrushDrop, Delay, ResistanceDrift, StribeckFriction
from pmdc_ident.core.motors import MotorSpec, load_motor
from pmdc_ident.node_logic.drift_monitor import DriftMonitor, DriftReport

SEED000 = load_motor("seed000_ebike")
RTOL = 1e-6  # rounding of another libm, not a change of behaviour

# sample index -> measured current (A), speed (rad/s), encoder angle (rad)
SAMPLES = {
    700: (5.925948775417175, 52.7297065641324, 3.2459033471660166),
    1000: (-13.253041984345272, 105.9218982185982, 31.228780879775883),
    1500: (5.295977176945606, -33.28658575490388, 19.95095412724065),
    2100: (4.483440067280818, 167.412292546019, 56.41214347449446),
    2500: (-0.012468837425566363, 174.29230614249292, 128.32362882978543),  # coasting
    2999: (0.015278547327817558, 155.63178130607483, 210.60635829197122),
}
PLANT_R_OHM = 1.540908236232627
# report -> quantity -> (estimate, 95 % half-interval)
REPORTS = {
    15: {
        "resistance": (1.4894590877680733, 0.02445821863229892),
        "back_emf": (0.06593621261466247, 0.0017144990948536924),
        "friction": (0.01878774731908543, 0.006060775603042843),
        "delay": (0.0034413296966960545, 0.0011853527151220236),
    },
    29: {
        "resistance": (1.516144319455683, 0.03589699021443512),
        "back_emf": (0.06699322597582079, 0.0012411727353354757),
        "friction": (0.023908771605569305, 0.006451202980864646),
        "delay": (0.003556884914388703, 0.0016079318134626),
    },
}


@pytest.fixture(scope="module")
def scripted_run() -> tuple[SimBackend, list, list[DriftReport]]:
    """3 s at 1 kHz: standing with the armature open, four voltage steps (heating,
    reversals through stiction), then the armature opened and the motor coasting; the
    drift monitor fed in 20 ms batches as the node feeds it."""
    model = SEED000.model.with_effects(
        ResistanceDrift(0.002, 30.0, 0.2),
        StribeckFriction(0.01, 5.0),
        Delay(0.002, 0.001),
        BrushDrop(0.3, 0.5),
    )
    spec = MotorSpec("pinned", model, SEED000.sensors, SEED000.limits)
    clock = [0.0]
    backend = SimBackend(spec, 1e-3, clock=lambda: clock[0], seed=3)
    backend.start()
    monitor = DriftMonitor(SEED000)
    levels = [12.0, -12.0, 6.0, 18.0]
    telemetry: list = []
    reports: list[DriftReport] = []
    for k in range(1, 151):
        t = k * 0.02
        if 0.6 <= t < 2.2:
            backend.command_voltage(levels[int((t - 0.6) / 0.4)])
        elif t >= 2.2 and not backend.armature_open:
            backend.open_armature()
        clock[0] = t
        batch = backend.poll()
        telemetry += batch
        a = np.array([(s.time_s, s.voltage_cmd_v, s.current_a, s.speed_rad_s) for s in batch])
        reports += monitor.process(a[:, 0], a[:, 1], a[:, 2], a[:, 3])
    return backend, telemetry, reports


def test_the_simulated_backend_reads_the_pinned_samples(scripted_run) -> None:
    backend, telemetry, _ = scripted_run
    assert len(telemetry) == 3001
    for k, expected in SAMPLES.items():
        s = telemetry[k]
        got = (s.current_a, s.speed_rad_s, s.position_rad)
        assert got == pytest.approx(expected, rel=RTOL), k
    assert backend.plant.resistance_ohm == pytest.approx(PLANT_R_OHM, rel=RTOL)


def test_the_drift_monitor_reports_the_pinned_estimates(scripted_run) -> None:
    _, _, reports = scripted_run
    assert len(reports) == 30
    for k, quantities in REPORTS.items():
        for name, expected in quantities.items():
            q = reports[k].quantity(name)
            assert (q.value, q.ci95) == pytest.approx(expected, rel=RTOL), (k, name)
