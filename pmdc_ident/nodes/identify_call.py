"""The one identification call shared by the online node and ``pmdc-ident identify`` (ROS-free).

The node identifies its session with :func:`identify_session_run`, which runs the
pipeline of ``pmdc-ident identify`` (:func:`pmdc_ident.core.estimators.identify.identify`
on the run's segments) with that command's default options; ``fixed`` is its
``--fix NAME=VALUE`` list. So ``pmdc-ident identify <bag> [--fix ...]`` on a laptop
prints the same parameters as the node published, and the JSON is the same
document ``pmdc-ident identify --json`` writes.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from pmdc_ident.core.data import Run
from pmdc_ident.core.motors import motor_to_yaml

__all__ = ["IdentifyOutput", "identify_session_run"]


@dataclass(frozen=True)
class IdentifyOutput:
    json_text: str  # the document of ``pmdc-ident identify --json``
    yaml_text: str  # the motor file of ``pmdc-ident identify --yaml``
    table: str  # the text report the command prints
    values: dict[str, float]


def identify_session_run(
    run: Run,
    fixed: Mapping[str, float] | None = None,
    name: str = "identified",
    extra: Mapping[str, Any] | None = None,
) -> IdentifyOutput:
    """Identify a session's run exactly as ``pmdc-ident identify DATA --fix ...`` does.

    ``extra`` entries are added to the JSON document (the node adds how complete its
    driver samples were).
    """
    from pmdc_ident.core.estimators.identify import ModelChoice, identify, merge_runs
    from pmdc_ident.core.estimators.output_error import CLOSURE_KT_KE

    result = identify(
        merge_runs([run]),
        sources=(run.source,),
        fixed=dict(fixed or {}),
        closure=CLOSURE_KT_KE,
        model=ModelChoice.AUTO.value,
        holdout=True,
        bootstrap=0,
    )
    header = "# Motor file written by `pmdc-ident identify`; load_motor(path) reads it.\n"
    return IdentifyOutput(
        json_text=json.dumps({**result.to_json_dict(), **(extra or {})}, indent=2, allow_nan=False)
        + "\n",
        yaml_text=header + motor_to_yaml(result.motor_spec(name)),
        table=result.text_report(),
        values={k: p.value for k, p in result.parameters.items()},
    )
