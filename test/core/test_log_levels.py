"""One log-level vocabulary: ``LogLevel`` (issue 26, problem 5), never a level's name as a
string where the ROS-free code hands a line to a node's logger."""

from __future__ import annotations

import ast

from helpers.paths import REPO

LEVEL_WORDS = {"debug", "info", "warn", "warning", "error", "fatal"}
LOG_CALLS = {"log": 0, "_log": 0, "_say": 1}  # the callable's name: the level's position


def _level_literals(tree: ast.AST) -> list[int]:
    """Lines where a level is written as a string: the level argument of a log call, or
    the first item of a ``(level, text)`` note."""
    lines = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            k = LOG_CALLS.get(name)
            if k is not None and len(node.args) > k:
                arg = node.args[k]
                if isinstance(arg, ast.Constant) and arg.value in LEVEL_WORDS:
                    lines.append(node.lineno)
        elif isinstance(node, ast.Tuple) and len(node.elts) == 2:
            first = node.elts[0]
            if isinstance(first, ast.Constant) and first.value in LEVEL_WORDS:
                lines.append(node.lineno)
    return sorted(lines)


def test_no_log_level_is_a_string_in_the_package():
    found = []
    for path in sorted((REPO / "pmdc_ident").rglob("*.py")):
        for line in _level_literals(ast.parse(path.read_text(encoding="utf-8"))):
            found.append(f"{path.relative_to(REPO)}:{line}")
    assert found == [], "use pmdc_ident.core.enums.LogLevel"


def test_the_scan_finds_levels_written_as_strings():
    code = (
        "self.ports.log('info', 'x')\nlog(LogLevel.INFO, 'y')\nnotes.append(('warning', 'z'))\n"
        "self._say('clamped', 'warning', 't')\nd = {'error': why}\n"
    )
    assert _level_literals(ast.parse(code)) == [1, 3, 4]
