"""An independent benchmark of the sim-to-real diagnosis (issue 11), ROS-free.

The generator here shares no equation with the candidate library of
:mod:`pmdc_ident.core.diagnosis`: it has its own motors (:mod:`.motors`), its own
integrator with switching-aware friction (:mod:`.plant`), its own effect
equations, several per vocabulary name (:mod:`.truth`), and its own sensor
models as real drivers have them (:mod:`.sensors`). From the rest of the project
the generator imports only :class:`~pmdc_ident.core.params.MotorParams` (the base
motor parameters), the session's default test plan
(:func:`~pmdc_ident.core.excitation.default_plan`, the shapes a user records) and
the numba wrapper; ``test/benchmark/test_benchmark_generator.py`` checks that. The
diagnosis reads each run from a CSV file that holds no truth (:mod:`.runner`);
:mod:`.scoring` and :mod:`.report` turn the outcomes into the figures a
reviewer checks.
"""

from __future__ import annotations
