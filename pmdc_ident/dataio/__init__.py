"""Reading and writing runs: CSV (``csvio``) and rosbag2/MCAP (``bagio``), ROS-free."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from pmdc_ident.core.data import Run
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.errors import option_name as opt

__all__ = ["load_data"]


def load_data(
    path: str | Path,
    columns: Mapping[str, str] | None = None,
    scale: Mapping[str, float] | None = None,
) -> Run:
    """Load one DATA argument: a CSV file, an ``.mcap`` file or a rosbag2 directory.

    ``columns`` and ``scale`` (CSV only, see :func:`~pmdc_ident.dataio.csvio.read_csv`)
    map schema names to the file's own headers and multiply columns to SI.
    """
    from pmdc_ident.core.safe_write import protect

    p = Path(path)
    if not p.exists():
        msg = f"{p}: no such file or directory"
        raise DataError(msg)
    protect([p])  # what a command reads, it never writes (core.safe_write)
    if p.is_dir() or p.suffix.lower() == ".mcap":
        if columns or scale:
            msg = f"{p}: {opt('column')} and unit scales apply to CSV files only (a bag is in SI)"
            raise DataError(msg)
        from pmdc_ident.dataio.bagio import read_bag

        return read_bag(p)
    if p.suffix.lower() in (".csv", ".txt"):
        from pmdc_ident.dataio.csvio import read_csv

        return read_csv(p, columns=columns, scale=scale)
    if p.suffix.lower() in (".xlsx", ".xls", ".ods", ".numbers"):
        msg = (
            f"{p}: a spreadsheet, not a CSV file: save it as CSV (comma-separated values, "
            "a header line naming the columns t, voltage, current, position/speed)"
        )
        raise DataError(msg)
    if p.suffix.lower() in (".db3", ".bag"):
        kind = "a ROS 1 bag" if p.suffix.lower() == ".bag" else "a sqlite3 rosbag2 file"
        msg = (
            f"{p}: {kind}; pmdc_ident reads rosbag2 MCAP bags: convert it (ros2 bag convert "
            "to storage mcap, or rosbags-convert) or export it as CSV"
        )
        raise DataError(msg)
    msg = (
        f"{p}: unknown data format {p.suffix or '(no suffix)'} (expected a .csv or .txt "
        "file, an .mcap file or a rosbag2 directory)"
    )
    raise DataError(msg)
