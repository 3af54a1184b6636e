"""The output-error problem's analytic gradient against central finite differences."""

from __future__ import annotations

from collections.abc import Iterable

import pytest


def assert_gradient_matches_fd(prob, indices: Iterable[int], labels=None) -> None:  # type: ignore[no-untyped-def]
    """``prob.evaluate``'s gradient of ``|r|^2 / 2`` at ``prob.z0()`` equals the central
    difference in each of ``indices`` (relative step 1e-6) within 1e-4."""
    z = prob.z0()
    _r, _a, g = prob.evaluate(z, True)
    for j in indices:
        h = 1e-6 * max(1.0, abs(z[j]))
        zp, zm = z.copy(), z.copy()
        zp[j] += h
        zm[j] -= h
        rp, _, _ = prob.evaluate(zp, False)
        rm, _, _ = prob.evaluate(zm, False)
        fd = (0.5 * rp @ rp - 0.5 * rm @ rm) / (2 * h)
        assert g[j] == pytest.approx(fd, rel=1e-4), labels[j] if labels else j
