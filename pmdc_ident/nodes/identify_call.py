"""The one identification call shared by the online node and ``pmdc-ident identify`` (ROS-free).

The node identifies its session with :func:`identify_session_run`; offline
re-identification of the session's bag goes through the same function with the
same options (``fixed`` = the ``--fix NAME=VALUE`` list), so both print the
same parameters. The JSON is the ``pmdc-ident identify --json`` document.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from pmdc_ident.core.data import Run
from pmdc_ident.core.errors import ParameterError

__all__ = ["IdentifyOutput", "identify_session_run", "parse_fix"]


@dataclass(frozen=True)
class IdentifyOutput:
    json_text: str
    yaml_text: str
    table: str
    values: dict[str, float]


def parse_fix(items: Sequence[str]) -> dict[str, float]:
    """``["L=3e-4", ...]`` -> ``{"L": 3e-4}`` (the ``--fix`` syntax)."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep or not name.strip():
                raise ValueError
            out[name.strip()] = float(value)
        except ValueError:
            msg = f"fix {item!r}: expected NAME=VALUE, e.g. L=0.0003"
            raise ParameterError(msg) from None
    return out


def identify_session_run(run: Run, fixed: Mapping[str, float] | None = None) -> IdentifyOutput:
    """Identify a session's run exactly as ``pmdc-ident identify DATA --fix ...`` does."""
    from pmdc_ident.commands.identify import identify_for_output

    return identify_for_output(run, dict(fixed or {}))
