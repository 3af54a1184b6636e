"""The application service: ``identify``, ``diagnose`` and ``check`` as data in, documents
out, below the command line (:mod:`pmdc_ident.commands`) and the identification node
(:mod:`pmdc_ident.nodes`), above the numerics. ROS-free and free of ``argparse``.
"""

from pmdc_ident.app.options import (
    CLI_NAMES,
    CheckOptions,
    DiagnoseOptions,
    IdentifyOptions,
    InputOptions,
)
from pmdc_ident.app.service import (
    CheckDocuments,
    DiagnoseDocuments,
    IdentifyDocuments,
    check_inputs,
    diagnose_inputs,
    identify_inputs,
)

__all__ = [
    "CLI_NAMES",
    "CheckDocuments",
    "CheckOptions",
    "DiagnoseDocuments",
    "DiagnoseOptions",
    "IdentifyDocuments",
    "IdentifyOptions",
    "InputOptions",
    "check_inputs",
    "diagnose_inputs",
    "identify_inputs",
]
