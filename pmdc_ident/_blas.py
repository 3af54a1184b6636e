"""One BLAS thread per process in the processes this package starts.

Our matrices are small (a few dozen parameters; dot products over a segment),
and on a shared machine the extra BLAS threads only spin waiting for a core:
with OpenBLAS's default (one thread per CPU) ``pmdc-ident identify`` on a 60 s
run used 2.7 s of CPU instead of 1.0 s on a loaded 2-core machine, for the same
parameters. The command line and the nodes therefore ask for one thread -
unless the user already chose, through the usual variables - before numpy is
imported (the processes they start inherit the setting). Importing the core as a
library changes nothing.
"""

from __future__ import annotations

import os
import sys

__all__ = ["BLAS_THREAD_VARIABLES", "limit_blas_threads"]

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")


def limit_blas_threads() -> bool:
    """Set each unset BLAS thread variable to 1 (child processes inherit it); False when
    numpy is already loaded in this process (its BLAS has read them: too late here)."""
    for name in BLAS_THREAD_VARIABLES:
        os.environ.setdefault(name, "1")
    return "numpy" not in sys.modules
