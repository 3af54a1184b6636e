"""The version of the JSON documents the package writes and publishes.

Carried as ``schema_version`` by the identification result (``pmdc-ident identify
--json``, ``parameters.json``, the ``identified_parameters`` topic) and by the nodes'
``status``, ``progress``, ``model_drift`` and ``reidentify_suggested`` messages; the
schemas are in ``docs/integration.md``. Keys may be added under one version; a key
removed, renamed or changed in meaning or unit raises it.
"""

from __future__ import annotations

__all__ = ["SCHEMA_VERSION"]

SCHEMA_VERSION = 1
