"""Where a command may write: one set of rules for every output option.

Checked before any work starts, so a bad output path costs the user nothing:

* ``-`` names standard output (for options that write one document: JSON,
  YAML, CSV); everything else is a path.
* An output never replaces an input (a ``DATA`` file, a file inside a ``DATA``
  bag folder, a motor file the command reads), whatever spelling or link leads
  to it, and never takes an input's sidecar name (``RUN.csv.yaml``); a folder
  output is checked for each file the command writes into it.
* The folder an output goes into must exist: a mistyped folder is an error,
  not a tree of new folders (``--report DIR`` itself is created, its parent
  must exist).
* A file output must not name a folder, a folder output must not name a file,
  and a file output's name ends in the suffix of what is written.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from pmdc_ident.core.errors import PmdcError

__all__ = [
    "STDOUT",
    "OutputError",
    "check_distinct",
    "check_file_output",
    "check_folder_output",
    "check_inputs_distinct",
]

STDOUT = "-"


class OutputError(PmdcError):
    """An output option names a place the command must not or cannot write."""


Reads = Sequence["str | Path | tuple[str | Path, str]"]


def reads_of(inputs: Reads) -> list[tuple[str | Path, str]]:
    """(path, description) of what a command reads: a bare path is "the input PATH"."""
    out: list[tuple[str | Path, str]] = []
    for item in inputs:
        if isinstance(item, tuple):
            out.append(item)
        else:
            out.append((item, f"the input {item}"))
    return out


def _bag_holding(path: Path) -> Path | None:
    """The rosbag2 folder (``metadata.yaml`` and an ``.mcap``) ``path`` lies inside, if any:
    a recording no command writes into, whether it reads it or not."""
    try:
        folder = path.resolve().parent
    except (OSError, RuntimeError):
        return None
    for p in (folder, *folder.parents):
        try:
            if (p / "metadata.yaml").is_file() and any(p.glob("*.mcap")):
                return p
        except OSError:
            return None
    return None


def _check_not_input(option: str, path: Path, inputs: Reads) -> None:
    """The one test (``core.safe_write.conflict``): not an input, not inside a bag
    folder that is one, not an input's sidecar name."""
    from pmdc_ident.core.safe_write import conflict, sidecar_owner

    why = conflict(path, reads_of(inputs))
    owner = sidecar_owner(path)
    if why is None and owner is not None:
        why = f"that is the sidecar name of the recording {owner} (its units, read on every run)"
    bag = _bag_holding(path)
    if why is None and bag is not None:
        why = f"that is inside the bag folder {bag} (a recording; write outside it)"
    if why is not None:
        msg = f"{option} {path}: {why}; refusing to write over an input (choose another name)"
        raise OutputError(msg)


def _check_parent(option: str, path: Path) -> None:
    parent = path.parent
    if not parent.exists():
        msg = f"{option} {path}: folder {parent} does not exist (create it first)"
        raise OutputError(msg)
    if not parent.is_dir():
        msg = f"{option} {path}: {parent} is not a folder"
        raise OutputError(msg)


def check_file_output(
    option: str,
    value: str | None,
    inputs: Reads,
    *,
    suffixes: tuple[str, ...] = (),
    stdout_ok: bool = True,
) -> Path | str | None:
    """The checked target of a file option: ``None`` (not given), :data:`STDOUT` or a Path."""
    if value is None:
        return None
    if value == STDOUT:
        if not stdout_ok:
            msg = f"{option}: '-' (standard output) is not possible here; give a file name"
            raise OutputError(msg)
        return STDOUT
    if not value.strip():
        msg = f"{option}: empty file name"
        raise OutputError(msg)
    path = Path(value)
    if path.is_dir():
        msg = f"{option} {path}: is a folder; give a file name"
        raise OutputError(msg)
    if suffixes and path.suffix.lower() not in suffixes:
        want = " or ".join(suffixes)
        msg = f"{option} {path}: the file name must end in {want}"
        raise OutputError(msg)
    _check_parent(option, path)
    _check_not_input(option, path, inputs)
    if path.is_symlink():
        from pmdc_ident.core.safe_write import WriteRefusedError, refuse_link

        try:
            refuse_link(path, path.resolve(), option)
        except WriteRefusedError as exc:
            raise OutputError(str(exc)) from None
        _check_not_input(option, path.resolve(), inputs)
    return path


def check_folder_output(
    option: str,
    value: str | Path | None,
    inputs: Reads,
    *,
    must_be_new: bool = False,
    file_suffixes: tuple[str, ...] = (".csv", ".txt", ".json", ".yaml", ".yml", ".html"),
    writes: Sequence[str] = (),
) -> Path | None:
    """The checked target of a folder option (``--report DIR``, ``--bag OUTDIR``).

    ``writes``: the names of the files the command will write into it; none of them
    may be an input (``monitor X/drift.csv --report X`` would replace its input)."""
    if value is None:
        return None
    if not str(value).strip():
        msg = f"{option}: empty folder name"
        raise OutputError(msg)
    path = Path(value)
    if str(value) == STDOUT:
        msg = f"{option}: '-' (standard output) is not possible here; give a folder name"
        raise OutputError(msg)
    if path.exists() and not path.is_dir():
        msg = f"{option} {path}: exists and is not a folder"
        raise OutputError(msg)
    if must_be_new and path.exists():
        msg = f"{option} {path}: exists already and is never overwritten; give a new name"
        raise OutputError(msg)
    if path.suffix.lower() in file_suffixes:
        msg = f"{option} {path}: names a folder to create, not a {path.suffix} file"
        raise OutputError(msg)
    _check_parent(option, path)
    _check_not_input(option, path, inputs)
    for name in writes:
        _check_not_input(option, path / name, inputs)
    return path


def check_distinct(targets: dict[str, Path | str | None]) -> None:
    """No two options write to the same place (or both to standard output)."""
    seen: dict[str, str] = {}
    for option, target in targets.items():
        if target is None:
            continue
        key = STDOUT if target == STDOUT else str(Path(target).resolve())
        if key in seen:
            what = "standard output" if key == STDOUT else str(target)
            msg = f"{seen[key]} and {option} both write to {what}"
            raise OutputError(msg)
        seen[key] = option


def check_inputs_distinct(inputs: Sequence[str | Path]) -> None:
    """No DATA given twice (under any spelling): its samples would count twice."""
    seen: dict[str, str] = {}
    for src in map(str, inputs):
        try:
            key = str(Path(src).resolve())
        except (OSError, RuntimeError):
            key = src
        if key in seen:
            msg = (
                f"{src} is given twice (as {seen[key]!r} and {src!r}): "
                "its samples would count twice and the intervals shrink"
            )
            raise OutputError(msg)
        seen[key] = src
