"""A folder on a nearly full disk, for the "no half-written file" tests.

Where this process may mount (root, as here and in CI), a small tmpfs is mounted on
the folder and filled up to a few kilobytes: every write beyond them fails with
ENOSPC as on a real full disk. Elsewhere a fault-injecting wrapper stands in: every
``fsync`` of ``core.safe_write`` (each output is flushed to the disk before it is
renamed) fails with ENOSPC, as a disk that filled meanwhile would report it.
"""

from __future__ import annotations

import contextlib
import errno
import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest


def _mount(folder: Path, size_k: int) -> bool:
    if os.geteuid() != 0 or os.environ.get("PMDC_TEST_NO_TMPFS"):
        return False
    r = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size_k}k,mode=0777", "tmpfs", str(folder)],
        capture_output=True,
    )
    return r.returncode == 0


def _fill(folder: Path, leave_bytes: int) -> None:
    """Fill ``folder``'s file system up to ``leave_bytes`` of free space."""
    st = os.statvfs(folder)
    free = st.f_bavail * st.f_frsize
    if free > leave_bytes:
        with (folder / ".filler").open("wb") as fh:
            fh.write(b"\0" * (free - leave_bytes))


@contextlib.contextmanager
def nearly_full(
    folder: Path, *, leave_bytes: int = 8192, keep: dict[str, bytes] | None = None
) -> Iterator[str]:
    """``folder`` (created) with ``keep`` files in it and little space left; yields the
    mode ('tmpfs' or 'fsync-fault')."""
    folder.mkdir(parents=True, exist_ok=True)
    if _mount(folder, 512):
        try:
            for name, data in (keep or {}).items():
                (folder / name).write_bytes(data)
            _fill(folder, leave_bytes)
            yield "tmpfs"
        finally:
            subprocess.run(["umount", "-l", str(folder)], check=False)
        return
    for name, data in (keep or {}).items():
        (folder / name).write_bytes(data)
    import pmdc_ident.core.safe_write as sw

    real = os.fsync

    def fsync(fd: int) -> None:
        try:
            path = os.readlink(f"/proc/self/fd/{fd}")
        except OSError:
            path = ""
        if path.startswith(str(folder)):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fd)

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(sw.os, "fsync", fsync)
        yield "fsync-fault"


def files_in(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (the filler aside) and its bytes."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file() and p.name != ".filler"
    }
