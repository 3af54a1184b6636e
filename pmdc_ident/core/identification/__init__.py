"""Identification: the pipeline behind ``pmdc-ident identify`` and the node's worker.

The orchestrator (:mod:`.identify`), its result (:mod:`.results`), the per-parameter
view (:mod:`.estimate`) and the fit stage's checks (:mod:`.fit_checks`, :mod:`.bias`).
It orchestrates the toolbox :mod:`pmdc_ident.core.estimators`, which imports nothing
from here (``test/test_layers.py``).
"""
