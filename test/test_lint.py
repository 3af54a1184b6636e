"""One ruff configuration (pyproject.toml) for the whole tree, enforced by the tests."""

from __future__ import annotations

import subprocess
import sys

import pytest
from helpers.paths import REPO

# Same set as `make lint`; only the ones that exist yet.
CANDIDATES = ("pmdc_ident", "test", "benchmarks", "launch", "tools", "setup.py")
PATHS = [name for name in CANDIDATES if (REPO / name).exists()]


def _ruff(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "ruff", *args, *PATHS],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )


def test_lint_covers_the_package_and_the_tests():
    assert "pmdc_ident" in PATHS
    assert "test" in PATHS


@pytest.mark.parametrize(
    "args",
    [("check", "--no-cache"), ("format", "--check", "--no-cache")],
    ids=["ruff-check", "ruff-format"],
)
def test_ruff_reports_no_findings(args):
    result = _ruff(*args)
    assert result.returncode == 0, f"ruff {' '.join(args)}:\n{result.stdout}{result.stderr}"
