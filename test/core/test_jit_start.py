"""numba is imported at the first kernel call, without all of scipy.linalg; BLAS works.

A module defining kernels (``core.model``, imported by ``core.motors``) does not import
numba: the identification node reads its motor file without paying ~0.2 s of CPU for
it.
numba tests for BLAS with ``import scipy.linalg.cython_blas`` when it loads its
implementations (first compilation or cache load); ``pmdc_ident.core._jit`` registers
that extension module alone (2 ms instead of scipy.linalg's ~0.14 s CPU). Checked in a
fresh interpreter: a cached kernel runs without ``scipy.linalg``; afterwards
``scipy.linalg`` imports as usual and a numba function calling BLAS (``a @ b``) gives
numpy's answer.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from pmdc_ident.core import _jit

PROBE = """
import json, sys
import numpy as np
from pmdc_ident.core.model import expm_small
a = np.array([[0.0, 1.0], [-2.0, -3.0]])
e = expm_small(a)
before = "scipy.linalg" in sys.modules
import numba
import scipy.linalg
from scipy.linalg import cython_blas, expm
dot = numba.njit(lambda x, y: x @ y)
x = np.arange(12.0).reshape(3, 4)
y = np.arange(8.0).reshape(4, 2)
print(json.dumps({
    "scipy_linalg_before": before,
    "expm_ok": bool(np.allclose(e, expm(a), rtol=1e-12)),
    "blas_ok": bool(np.allclose(dot(x, y), x @ y)),
    "same_module": cython_blas is sys.modules["scipy.linalg.cython_blas"],
}))
"""


@pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")
def test_first_kernel_call_skips_scipy_linalg_and_blas_still_works() -> None:
    out = subprocess.run(
        [sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=300, check=True
    )
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res == {
        "scipy_linalg_before": False,
        "expm_ok": True,
        "blas_ok": True,
        "same_module": True,
    }, out.stderr


LAZY_PROBE = """
import json, sys
from pmdc_ident.core.motors import load_motor
import pmdc_ident.core.estimators.output_error.kernel as kernel
spec = load_motor("seed000_ebike")
before = "numba" in sys.modules
from pmdc_ident.core.model import simulate_linear
import numpy as np
sim = simulate_linear(spec.model.params, np.full(50, 12.0), 1e-3)
print(json.dumps({
    "numba_before": before,
    "numba_after": "numba" in sys.modules,
    "moved": float(sim.speed[-1]) > 0.0,
    # the lazy kernels in every module were replaced by numba's dispatchers
    "dispatchers": [type(kernel.fast_kernel).__name__, type(kernel.effects_kernel).__name__],
}))
"""


@pytest.mark.skipif(not _jit.HAVE_NUMBA, reason="numba not installed")
def test_reading_a_motor_imports_no_numba_and_the_first_kernel_call_compiles_all() -> None:
    out = subprocess.run(
        [sys.executable, "-c", LAZY_PROBE], capture_output=True, text=True, timeout=300, check=True
    )
    res = json.loads(out.stdout.strip().splitlines()[-1])
    assert res == {
        "numba_before": False,
        "numba_after": True,
        "moved": True,
        "dispatchers": ["CPUDispatcher", "CPUDispatcher"],
    }, out.stderr
