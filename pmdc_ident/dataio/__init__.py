"""Reading and writing runs: CSV (``csvio``) and rosbag2/MCAP (``bagio``), ROS-free."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from pmdc_ident.core.data import Run
from pmdc_ident.core.errors import DataError

__all__ = ["load_data"]


def load_data(path: str | Path, columns: Mapping[str, str] | None = None) -> Run:
    """Load one DATA argument: a CSV file, an ``.mcap`` file or a rosbag2 directory.

    ``columns`` (CSV only) maps schema names to the file's own headers.
    """
    p = Path(path)
    if not p.exists():
        msg = f"{p}: no such file or directory"
        raise DataError(msg)
    if p.is_dir() or p.suffix.lower() == ".mcap":
        if columns:
            msg = f"{p}: --column applies to CSV files only (a bag has fixed topics)"
            raise DataError(msg)
        from pmdc_ident.dataio.bagio import read_bag

        return read_bag(p)
    if p.suffix.lower() in (".csv", ".txt"):
        from pmdc_ident.dataio.csvio import read_csv

        return read_csv(p, columns=columns)
    msg = f"{p}: unknown data format (expected .csv, .mcap or a rosbag2 directory)"
    raise DataError(msg)
