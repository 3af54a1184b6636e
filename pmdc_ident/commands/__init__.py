"""Sub-commands of ``pmdc-ident`` (see :mod:`pmdc_ident.cli`)."""
