"""The short test sequence (seed-001 motor, tau_m = 50 ms: about 5 s of driver time),
as identification-node parameters; shared by the node tests, the controller tests and
benchmarks/bench_session.py."""

from __future__ import annotations

SHORT_SEQUENCE: dict[str, float | int] = {
    "sequence.staircase_levels": 3,
    "sequence.staircase_hold_tau": 5.0,
    "sequence.step_hold_tau": 5.0,
    "sequence.sweep_duration_tau": 20.0,
    "sequence.coast_spinup_tau": 4.0,
    "sequence.coast_open_s": 1.0,
}
