"""One exit-status vocabulary: ``ExitCode``, and the reference table that documents it."""

from __future__ import annotations

import ast
import re

from helpers.paths import REPO

from pmdc_ident import cli
from pmdc_ident.core.enums import ExitCode
from pmdc_ident.process.launching import exit_meaning


def test_the_exit_statuses_in_the_reference_are_the_enums_values():
    text = (REPO / "docs" / "reference.md").read_text(encoding="utf-8")
    section = text.split("## 4. Exit statuses", 1)[1].split("\n## ", 1)[0]
    documented = {int(m) for m in re.findall(r"^\|[^|]*\| (\d+) \|", section, re.MULTILINE)}
    assert documented == {int(code) for code in ExitCode}


def test_no_module_defines_an_exit_status_of_its_own():
    """A constant ``EXIT_* = <int>`` anywhere in the package is a second vocabulary."""
    own = []
    for path in sorted((REPO / "pmdc_ident").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
                names = [t.id for t in node.targets if isinstance(t, ast.Name)]
                if any(n.startswith("EXIT_") for n in names):
                    own.append(f"{path.relative_to(REPO)}:{node.lineno}")
    assert own == []


def test_the_command_lines_statuses_are_the_enums_members():
    assert cli.EXIT_INTERNAL_ERROR is ExitCode.FAILED
    assert cli.EXIT_USER_ERROR is ExitCode.USER_ERROR
    assert cli.EXIT_INTERRUPTED is ExitCode.INTERRUPTED
    assert [int(c) for c in ExitCode] == [0, 1, 2, 3, 130]  # the values users script against


def test_a_launch_names_the_identification_nodes_statuses_in_words():
    assert exit_meaning("identification_node", 2) == "refused before anything moved"
    assert exit_meaning("identification_node", ExitCode.ABORTED) == "session aborted"
    assert exit_meaning("identification_node", 130) == "interrupted"
    assert exit_meaning("driver_node", 2) == "failed"
    assert exit_meaning("driver_node", 0) == "done"
