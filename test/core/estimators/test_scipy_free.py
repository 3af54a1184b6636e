"""The scipy-free pieces of the classical chain and the equation error agree with scipy.

``t_quantile`` against ``scipy.special.stdtrit``, ``logm_2x2`` against
``scipy.linalg.logm`` on motor-like matrices, the package's one Levenberg-Marquardt
solver on a curve with a known minimum; and the classical chain imports neither
``scipy.optimize`` nor ``scipy.special`` (their import was 0.3 s of CPU in every
``pmdc-ident identify``: ``benchmarks/bench_scipy_imports.py``).
"""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from helpers.paths import REPO
from scipy.linalg import expm, logm
from scipy.special import stdtrit

from pmdc_ident.core.estimators.classical import coast_speed, coast_speed_jacobian
from pmdc_ident.core.estimators.equation_error import logm_2x2
from pmdc_ident.core.estimators.solver import least_squares
from pmdc_ident.core.estimators.student_t import t_quantile


@pytest.mark.parametrize("p", [0.975, 0.95, 0.995, 0.9, 0.6, 0.025])
def test_t_quantile_matches_scipy(p: float) -> None:
    dofs = [*np.arange(1.0, 30.0, 0.25), *range(30, 1200, 7), 2000, 5e3, 1e4, 6e4, 1e6, 1e9]
    ref = np.array([stdtrit(d, p) for d in dofs])
    ours = np.array([t_quantile(p, d) for d in dofs])
    assert np.max(np.abs(ours / ref - 1.0)) < 1e-11


def test_t_quantile_refuses_what_it_does_not_define() -> None:
    for p, dof in ((0.0, 5), (1.0, 5), (0.9, 0.5), (0.9, float("nan"))):
        with pytest.raises(ValueError):
            t_quantile(p, dof)


def test_logm_2x2_matches_scipy_on_discretised_motors() -> None:
    rng = np.random.default_rng(7)
    worst = 0.0
    for _ in range(2000):
        R, L = 10 ** rng.uniform(-1, 1.5), 10 ** rng.uniform(-5, -1)
        Ke, J, B = 10 ** rng.uniform(-3, 0), 10 ** rng.uniform(-6, -1), 10 ** rng.uniform(-7, -2)
        A = np.array([[-R / L, -Ke / L], [Ke / J, -B / J]])
        phi = expm(A * 10 ** rng.uniform(-4.5, -1.3))
        phi += rng.normal(size=(2, 2)) * 10 ** rng.uniform(-9, -3)
        if phi[0, 0] <= 0.05:  # equation_error uses the logarithm only above this
            continue
        ref = logm(phi)
        ours = logm_2x2(phi)
        if np.iscomplexobj(ref) and np.max(np.abs(ref.imag)) > 1e-6 * np.max(np.abs(ref.real)):
            assert ours is None
            continue
        assert ours is not None
        worst = max(worst, float(np.max(np.abs(ours - ref.real)) / np.max(np.abs(ref.real))))
    assert worst < 1e-7


def test_logm_2x2_of_rotations_and_negative_eigenvalues() -> None:
    th = 2.5  # complex eigenvalues with a negative real part: the real principal log
    rot = 0.7 * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    np.testing.assert_allclose(logm_2x2(rot), logm(rot).real, rtol=1e-13, atol=1e-15)
    assert logm_2x2(np.diag([0.5, -0.2])) is None
    assert logm_2x2(np.diag([-0.5, -0.2])) is None
    assert logm_2x2(np.diag([0.5, 0.0])) is None


def test_the_solver_finds_a_coast_curves_parameters() -> None:
    t = np.linspace(0.0, 4.0, 400)
    truth = (120.0, 0.4, 15.0)
    w = coast_speed(t, *truth) + np.random.default_rng(1).normal(0.0, 0.01, t.size)
    sol = least_squares(
        lambda z: coast_speed(t, *z) - w,
        lambda z: coast_speed_jacobian(t, *z),
        [100.0, 0.2, 10.0],
    )
    np.testing.assert_allclose(sol.x, truth, rtol=1e-3)
    grad = sol.jac.T @ sol.fun  # at the minimum the gradient vanishes
    assert np.all(np.abs(grad) <= 1e-8 * np.linalg.norm(sol.jac, axis=0) * np.linalg.norm(w))


def test_coast_speed_jacobian_is_its_derivative() -> None:
    t = np.linspace(0.0, 5.0, 60)
    for x in ((100.0, 0.3, 20.0), (100.0, 1e-13, 5.0), (-50.0, 0.2, -3.0)):
        jac = coast_speed_jacobian(t, *x)
        for k in range(3):
            h = 1e-6 * max(abs(x[k]), 1e-9)
            up, down = list(x), list(x)
            up[k] += h
            down[k] -= h
            num = (coast_speed(t, *up) - coast_speed(t, *down)) / (2 * h)
            np.testing.assert_allclose(jac[:, k], num, rtol=1e-6, atol=1e-6 * np.abs(num).max())


def test_the_classical_chain_imports_no_scipy_optimize_or_special() -> None:
    probe = (
        "import json, sys\n"
        "from helpers.paths import FIXTURES\n"
        "from pmdc_ident.dataio import load_data\n"
        "from pmdc_ident.core.estimators.classical import classical_chain\n"
        "from pmdc_ident.core.estimators.equation_error import fit_equation_error\n"
        "runs = [load_data(FIXTURES / n) for n in ('seed000_table4.csv', "
        "'seed000_retardation.csv')]\n"
        "classical_chain([s for r in runs for s in r.segments])\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('scipy.'))))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
        cwd=REPO / "test",
    )
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert not [m for m in loaded if m.startswith(("scipy.optimize", "scipy.special"))]
