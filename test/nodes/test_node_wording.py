"""The identification node names its ROS parameter where the command line names a flag
(issue 26, problem 5): a bad ``fix`` item, and every hint of its identification."""

from __future__ import annotations

import pytest

from pmdc_ident.core.errors import PmdcError
from pmdc_ident.process.parameter_tables import IDENTIFICATION
from pmdc_ident.process.settings import controller_config


@pytest.mark.parametrize(
    ("item", "line"),
    [
        ("R=abc", "parameter fix R: 'abc' is not a number"),
        ("L", "parameter fix expects NAME=VALUE (e.g. L=3e-4), got 'L'"),
        ("Q=1", "parameter fix Q: unknown parameter (can be fixed: "),
        ("R=-1", "parameter fix R=-1: outside the physical range of the armature resistance"),
    ],
)
def test_a_bad_fix_item_names_the_ros_parameter_not_the_flag(item, line):
    values = {**IDENTIFICATION.defaults(), "motor": "seed001_110v", "fix": [item]}
    with pytest.raises(PmdcError) as info:
        controller_config(values)
    assert str(info.value).startswith(line) and "--fix" not in str(info.value), info.value


def test_the_node_document_names_its_parameter_where_the_command_names_its_flag(tmp_path):
    import json

    from pmdc_ident.cli import main
    from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
    from pmdc_ident.core.motors import load_motor
    from pmdc_ident.dataio.csvio import write_csv
    from pmdc_ident.process.identify_call import identify_session_run

    spec = load_motor("seed001_110v")
    plan = plan_for_motor(spec, 1e-3, SequenceConfig(staircase_levels=2, coast_open_s=0.3))
    run = synthesize_run(spec.model, plan, spec.sensors, seed=3, source="session")
    path = str(write_csv(run, tmp_path / "session.csv"))
    assert main(["identify", path, "--json", str(tmp_path / "cli.json"), "--quiet"]) == 0
    cli = json.loads((tmp_path / "cli.json").read_text())
    node = json.loads(identify_session_run(run, source=path).json_text)
    # Kt under the closure Kt = Ke: what would measure it, in each caller's words
    assert "--fix Kt=..." in cli["parameters"]["Kt"]["reason"]
    assert "parameter fix Kt=..." in node["parameters"]["Kt"]["reason"]
    assert "--fix" not in json.dumps(node)
