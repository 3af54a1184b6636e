"""Run ``uv pip ARGS...`` on the index pip is configured for (``make venv``).

usage: PYTHON tools/uv_pip.py UV ARGS...   (installs into PYTHON's environment)

uv installs the pinned set several times faster than pip (parallel downloads and
unpacking) but reads no ``pip.conf`` and no ``PIP_*`` variable. On a machine whose pip
is set to a mirror, extra indexes, local wheel folders or a site constraint file, uv
given no options would look elsewhere, or nowhere. This reads pip's own view of its
configuration (``pip config list``: files and environment) and hands uv the same
sources, so both install the same files. pip takes the best version from all its
sources at once; uv does that with ``--index-strategy unsafe-best-match``.

Only the standard library: it runs in the fresh venv before anything is installed.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys

#: pip's option -> uv's, for the options that say where packages come from; those of
#: several values take them separated by white space, as pip does
_SOURCES = {
    "index-url": ("--index-url", False),
    "extra-index-url": ("--extra-index-url", True),
    "find-links": ("--find-links", True),
    "constraint": ("--constraint", True),
}
#: pip's sections, the one that wins last: its variables override its files, and the
#: ``[install]`` section overrides ``[global]``
_PRECEDENCE = ("global", "install", ":env:")


def pip_settings(python: str) -> dict[str, str]:
    """pip's configured values by option name (``pip config list``), in pip's precedence."""
    listing = subprocess.run(
        [python, "-m", "pip", "config", "list"],
        capture_output=True,
        text=True,
        check=False,
    )
    if listing.returncode != 0:
        raise RuntimeError(f"pip config list: {listing.stderr.strip()}")
    found: dict[str, dict[str, str]] = {}
    for line in listing.stdout.splitlines():
        key, sep, raw = line.partition("=")
        section, dot, name = key.rpartition(".")
        if not sep or not dot:
            continue
        try:
            value = ast.literal_eval(raw)
        except (ValueError, SyntaxError):
            continue
        found.setdefault(name, {})[section] = str(value)
    settings = {}
    for name, by_section in found.items():
        for section in _PRECEDENCE:
            if section in by_section:
                settings[name] = by_section[section]
    return settings


def uv_options(settings: dict[str, str]) -> tuple[list[str], dict[str, str]]:
    """uv's command-line options and environment for pip's ``settings``."""
    args = ["--index-strategy", "unsafe-best-match"]
    for name, (option, several) in _SOURCES.items():
        value = settings.get(name, "").strip()
        for item in value.split() if several else [value] if value else []:
            args += [option, item]
    if settings.get("no-index", "").lower() in ("1", "true", "yes", "on"):
        args.append("--no-index")
    env = {}
    if settings.get("cert"):
        env["SSL_CERT_FILE"] = settings["cert"]
    if settings.get("timeout") or settings.get("default-timeout"):
        env["UV_HTTP_TIMEOUT"] = settings.get("timeout") or settings["default-timeout"]
    return args, env


def main(argv: list[str]) -> int:
    if len(argv) < 3:
        print(__doc__.splitlines()[2], file=sys.stderr)
        return 2
    uv, command, *rest = argv[1:]
    python = sys.executable
    try:
        args, env = uv_options(pip_settings(python))
    except (OSError, RuntimeError) as exc:
        print(f"uv_pip: cannot read pip's configuration ({exc})", file=sys.stderr)
        return 1
    cmd = [uv, "pip", command, "--python", python, *args, *rest]
    try:
        return subprocess.run(cmd, env={**os.environ, **env}, check=False).returncode
    except OSError as exc:  # no uv (its bootstrap failed): the caller falls back to pip
        print(f"uv_pip: cannot run {uv} ({exc})", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
