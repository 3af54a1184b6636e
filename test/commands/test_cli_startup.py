"""``pmdc-ident --help`` and argument errors answer without the numerical stack.

Building the command line (every command's ``add_arguments``) must not import
numpy, scipy, numba, matplotlib or the bag libraries: they cost about a second of
CPU time, which a user pays for a help text. The check is on what a fresh
interpreter has imported (deterministic), not on a time (the machine is shared).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from pmdc_ident.commands.identify import MODEL_CHOICES
from pmdc_ident.core import _jit
from pmdc_ident.core.identification.identify import ModelChoice

HEAVY = ("numpy", "scipy", "numba", "llvmlite", "matplotlib", "rosbags", "mcap", "yaml")

_PROBE = """
import json, sys
from pmdc_ident import cli
argv = sys.argv[1:]
try:
    rc = cli.main(argv)
except SystemExit as exc:
    rc = exc.code
heavy = {heavy!r}
print(json.dumps([rc, sorted({{m.split(".")[0] for m in sys.modules}} & set(heavy))]))
"""


@pytest.mark.parametrize(
    "argv",
    [
        ["--help"],
        ["identify", "--help"],
        ["diagnose", "--help"],
        ["export", "--help"],
        ["check", "--help"],
        ["export-model", "--help"],
        ["monitor", "--help"],
        ["benchmark", "--help"],
        ["virtual-board", "--help"],
        ["identify", "--bootstrap"],  # an argument error
        ["identify", "run.csv", "--bootstrap", "-1"],  # a value error found before loading
        ["no-such-command"],
    ],
    ids=lambda a: " ".join(a),
)
def test_help_and_argument_errors_import_no_numerical_stack(argv: list[str]) -> None:
    out = subprocess.run(
        [sys.executable, "-c", _PROBE.format(heavy=HEAVY), *argv],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    rc, heavy = json.loads(out.stdout.strip().splitlines()[-1])
    assert heavy == []
    assert rc == (0 if "--help" in argv else 2), out.stderr  # help, or one line + exit 2


def test_a_command_imports_only_its_own_command_module() -> None:
    """``pmdc-ident check RUN`` does not pay for identify's or batch's imports."""
    probe = (
        "import json, sys\nfrom pmdc_ident import cli\n"
        "try:\n    cli.main(['check', '--help'])\nexcept SystemExit:\n    pass\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.startswith('pmdc_ident.commands.'))))"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe], capture_output=True, text=True, timeout=120, check=True
    )
    loaded = json.loads(out.stdout.strip().splitlines()[-1])
    assert "pmdc_ident.commands.check" in loaded
    assert not {"pmdc_ident.commands.identify", "pmdc_ident.commands.batch"} & set(loaded)


def test_core_package_names_resolve_lazily() -> None:
    import pmdc_ident.core as core

    for name in core.__all__:
        assert getattr(core, name) is not None
    assert set(core.__all__) <= set(dir(core))
    with pytest.raises(AttributeError):
        _ = core.no_such_name


def test_model_choices_of_the_command_are_the_enum() -> None:
    assert MODEL_CHOICES == tuple(m.value for m in ModelChoice)


_KERNEL = """
from pmdc_ident.core._jit import njit


@njit
def add_one(x):
    return x + 1.0
"""

_KERNEL_PROBE = """
import json, os
from pmdc_ident.core import _jit
import kernel_module
value = kernel_module.add_one(1.0)  # numba is imported and configured at the first call
cache = _jit._numba.config.CACHE_DIR
print(json.dumps({"value": value, "cache_dir": cache,
                  "files": sorted(os.listdir(cache)) if cache else []}))
"""


def _kernel_probe(tmp_path, locators: str, home: Path | None = None) -> dict:
    """Compile a kernel through ``_jit.njit`` with only ``locators`` allowed to numba
    and ``home`` as the user's home (default: one under ``tmp_path``)."""
    (tmp_path / "kernel_module.py").write_text(_KERNEL)
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR", "XDG_CACHE_HOME")}
    env.update(
        NUMBA_CACHE_LOCATOR_CLASSES=locators,
        TMPDIR=str(tmp_path),
        HOME=str(home or tmp_path / "home"),
    )
    env["PYTHONPATH"] = os.pathsep.join([str(tmp_path), env.get("PYTHONPATH", "")])
    out = subprocess.run(
        [sys.executable, "-c", _KERNEL_PROBE],
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_kernels_are_cached_in_a_folder_named_by_the_kernel_sources(tmp_path) -> None:
    res = _kernel_probe(tmp_path, "UserProvidedCacheLocator,IPythonCacheLocator")
    assert res["value"] == 2.0
    want = tmp_path / "home" / ".cache" / "pmdc_ident" / f"numba-{_jit.kernel_fingerprint()}"
    assert res["cache_dir"] == str(want)
    assert res["files"]  # the compiled kernel landed there


def test_a_change_in_any_kernel_source_moves_the_cache(tmp_path) -> None:
    # numba alone invalidates a cached kernel only when its own file changes; the
    # output-error kernel inlines model.effects_kernel from another file
    root = Path(_jit.__file__).resolve().parents[1]
    for rel in (*_jit.KERNEL_SOURCES, *_jit.KERNEL_CONSTANTS):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(root / rel, tmp_path / rel)
    before = _jit.kernel_fingerprint(tmp_path)
    assert before == _jit.kernel_fingerprint()
    with (tmp_path / "core" / "model.py").open("a") as f:
        f.write("# a changed crossing rule\n")
    after_model = _jit.kernel_fingerprint(tmp_path)
    assert after_model != before
    # the kernels freeze the slot numbers of the effects' layout when compiled
    with (tmp_path / "core" / "effects" / "layout.py").open("a") as f:
        f.write("# a moved slot\n")
    assert _jit.kernel_fingerprint(tmp_path) != after_model


def test_every_module_with_a_kernel_is_in_the_fingerprint() -> None:
    root = Path(_jit.__file__).resolve().parents[1]
    users = {
        str(p.relative_to(root))
        for p in root.rglob("*.py")
        if "core._jit import" in p.read_text() or "core import _jit" in p.read_text()
    }
    assert users | {"core/_jit.py"} == set(_jit.KERNEL_SOURCES)


def test_kernels_are_cached_privately_when_no_cache_location_is_writable(tmp_path) -> None:
    # As for a read-only installed package run by a user without a writable home:
    # numba finds no cache location beside the source nor in the user's cache.
    (tmp_path / "not_a_folder").write_text("")
    res = _kernel_probe(
        tmp_path, "UserProvidedCacheLocator,IPythonCacheLocator", tmp_path / "not_a_folder" / "h"
    )
    assert res["value"] == 2.0
    private = tmp_path / f"pmdc_ident-numba-{os.getuid()}"
    assert res["cache_dir"] == str(private / f"numba-{_jit.kernel_fingerprint()}")
    assert res["files"]  # the compiled kernel landed there


def test_kernels_still_run_when_nothing_can_be_cached(tmp_path) -> None:
    res = _kernel_probe(tmp_path, "IPythonCacheLocator")
    assert res["value"] == 2.0


_BLAS_PROBE = """
import json, os, sys
try:
    {setup}
except SystemExit:
    pass
print(json.dumps({{v: os.environ.get(v) for v in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}}))
"""


@pytest.mark.parametrize(
    ("setup", "preset", "want"),
    [
        ("from pmdc_ident import cli; cli.main(['--version'])", None, "1"),
        ("import pmdc_ident.nodes", None, "1"),
        ("import pmdc_ident.process", None, "1"),  # bringup, the worker: as the nodes
        ("from pmdc_ident import cli; cli.main(['--version'])", "2", "2"),  # the user's choice
        ("import numpy, pmdc_ident.nodes", None, "1"),  # too late here; for its children
        ("import pmdc_ident.core.model", None, None),  # a library user's process: untouched
    ],
)
def test_our_processes_ask_for_one_blas_thread(setup: str, preset: str | None, want) -> None:
    env = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    if preset is not None:
        env["OPENBLAS_NUM_THREADS"] = preset
    out = subprocess.run(
        [sys.executable, "-c", _BLAS_PROBE.format(setup=setup)],
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
        check=False,
    )
    assert json.loads(out.stdout.strip().splitlines()[-1])["OPENBLAS_NUM_THREADS"] == want


def test_in_process_calls_keep_a_collectable_heap() -> None:
    """Only the program itself (``main()`` without argv) freezes its heap before exit;
    tests and batch workers call ``main(argv)`` and must not accumulate frozen objects."""
    import gc

    from pmdc_ident import cli

    before = gc.get_freeze_count()
    assert cli.main(["identify", "run.csv", "--bootstrap", "-1"]) == 2  # in-process
    assert gc.get_freeze_count() == before
