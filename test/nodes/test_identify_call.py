"""The identification worker's warm-up covers what a session's identification runs."""

from __future__ import annotations

import sys

import pytest

from pmdc_ident.core._jit import HAVE_NUMBA
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor
from pmdc_ident.nodes.identify_call import identify_session_run, warm_up


def _kernels() -> dict[str, int]:
    """Every numba kernel of the package loaded so far, with its number of signatures."""
    from numba.core.registry import CPUDispatcher

    found = {}
    for name, module in list(sys.modules.items()):
        if not name.startswith("pmdc_ident"):
            continue
        for attr, value in vars(module).items():
            if isinstance(value, CPUDispatcher):
                found[f"{name}.{attr}"] = len(value.signatures)
    return found


@pytest.mark.skipif(not HAVE_NUMBA, reason="numba not installed")
def test_after_the_warm_up_a_session_identification_loads_no_kernel():
    spec = load_motor("seed001_110v")
    warm_up(spec)
    before = _kernels()
    # a session longer than the warm-up's, on another motor, with other noise
    other = load_motor("seed000_ebike")
    plan = plan_for_motor(other, 1e-3, SequenceConfig(staircase_levels=3, coast_open_s=0.5))
    out = identify_session_run(synthesize_run(other.model, plan, other.sensors, seed=3))
    assert out.values["R"] > 0
    assert _kernels() == before
