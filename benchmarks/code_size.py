"""Lines of the package, its largest modules and functions (a radon-like count).

    .venv/bin/python benchmarks/code_size.py [--root DIR] [--top N]

``--root`` is a source tree (default: this one), so two commits can be compared::

    git archive 9f585c2 pmdc_ident | tar -x -C /tmp/base
    .venv/bin/python benchmarks/code_size.py --root /tmp/base

Lines are physical lines of ``pmdc_ident/**/*.py``; a function's length runs from its
``def`` (decorators excluded) to its last line, nested functions counted in their
parent as well. With ``--grep NAME`` it also lists the modules that name ``NAME`` (an
effect's vocabulary name, say), the count of files a change to that effect may touch.
"""

from __future__ import annotations

import argparse
import ast
import statistics
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def functions(path: Path) -> list[tuple[int, str]]:
    """(lines, qualified name) of every function and method in ``path``."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out: list[tuple[int, str]] = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = (child.end_lineno or child.lineno) - child.lineno + 1
                out.append((n, f"{prefix}{child.name}"))
                visit(child, f"{prefix}{child.name}.")
            elif isinstance(child, ast.ClassDef):
                visit(child, f"{prefix}{child.name}.")

    visit(tree, "")
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", type=Path, default=ROOT)
    p.add_argument("--top", type=int, default=10)
    p.add_argument("--grep", action="append", default=[], metavar="NAME")
    args = p.parse_args()
    pkg = args.root / "pmdc_ident"
    files = sorted(pkg.rglob("*.py"))
    sizes = [(len(f.read_text(encoding="utf-8").splitlines()), f.relative_to(pkg)) for f in files]
    funcs = [(n, f"{f.relative_to(pkg)}:{name}") for f in files for n, name in functions(f)]
    total = sum(n for n, _ in sizes)
    lengths = [n for n, _ in funcs]
    print(f"{total} lines in {len(files)} modules, {len(funcs)} functions")
    print(
        f"function lines: median {statistics.median(lengths):g}, "
        f"mean {statistics.mean(lengths):.1f}, > 60 lines: {sum(n > 60 for n in lengths)}"
    )
    print(f"largest modules (top {args.top}):")
    for n, rel in sorted(sizes, reverse=True)[: args.top]:
        print(f"  {n:5d}  {rel}")
    print(f"largest functions (top {args.top}):")
    for n, name in sorted(funcs, reverse=True)[: args.top]:
        print(f"  {n:5d}  {name}")
    for word in args.grep:
        hits = [
            rel
            for _, rel in sorted(sizes, key=lambda s: str(s[1]))
            if word in (pkg / rel).read_text()
        ]
        print(f"modules naming {word!r}: {len(hits)}: {' '.join(str(h) for h in hits)}")


if __name__ == "__main__":
    main()
