"""The short test sequence (seed-001 motor, tau_m = 50 ms: about 5 s of driver time),
as identification-node parameters; shared by the node tests, the controller tests and
benchmarks/bench_session.py. And :func:`tiny_run`, a simulated run of a shorter one
for the file-format tests."""

from __future__ import annotations

from pmdc_ident.core.data import Run
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor

SHORT_SEQUENCE: dict[str, float | int] = {
    "sequence.staircase_levels": 3,
    "sequence.staircase_hold_tau": 5.0,
    "sequence.step_hold_tau": 5.0,
    "sequence.sweep_duration_tau": 20.0,
    "sequence.coast_spinup_tau": 4.0,
    "sequence.coast_open_s": 1.0,
}

# every test once, briefly (about 2.4 s of driver time on the seed-001 motor)
TINY_SEQUENCE = SequenceConfig(
    staircase_levels=2,
    staircase_hold_tau=3.0,
    step_hold_tau=3.0,
    sweep_duration_tau=6.0,
    coast_spinup_tau=3.0,
    coast_open_s=0.1,
)


def tiny_run(seed: int, dt_s: float = 1e-3) -> Run:
    """The seed-001 motor simulated through :data:`TINY_SEQUENCE` with sensor noise."""
    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, dt_s, TINY_SEQUENCE)
    return synthesize_run(spec.model, plan, spec.sensors, seed=seed)
