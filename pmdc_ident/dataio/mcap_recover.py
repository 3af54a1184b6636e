"""The readable part of an MCAP file that was never closed (recorder killed, disk full, cut copy).

A bag's ``.mcap`` gets its index and footer only when the recorder closes it; a
killed recorder leaves the data section alone, cut anywhere. The recorder closes
a chunk at least every half second, so everything but the last moments sits in
complete chunks. :func:`scan_mcap` reads the records from the start with the
``mcap`` library's ``StreamReader`` (the one library reader that needs no summary or
footer: ``rosbags``' reader and ``mcap``'s seeking reader refuse such a file), keeps
every complete chunk (decoded whole by ``breakup_chunk`` before any of its messages
is kept) and unchunked record, and stops at the first record that does not fit in
the file or does not parse. It returns the messages with their topics and what was
left out; any damage is a :class:`~pmdc_ident.core.errors.DataError` with one line,
never another exception.

Our own code is only what the library does not say: the byte offset after the last
complete record (the file position as each record is handed out), from which the
user's line says how many bytes were lost, and whether reading stopped at a record
the file cut short (:func:`_cut_at`: its length runs past the end - a cut, said as
such) or at a damaged one. The library costs some CPU, on a rare path: a ``make demo``
bag cut at 40 % (5.6 MB, 51 504 messages) takes 0.23 s where the hand-written record
walk this replaced took 0.063 s (3.6x; ``StreamReader`` alone 0.21 s:
``benchmarks/bench_bag_read.py --recovery-only``, edc30e8 for the old walk), small
beside the identification that follows; both read the same messages and stop at the
same byte on 65 cuts of that bag.
"""

from __future__ import annotations

import io
import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from pmdc_ident.core.errors import DataError
from pmdc_ident.core.markers import Marker, MarkerEvent

__all__ = ["Recovered", "cut_markers", "scan_mcap", "unfinished"]

MAGIC = b"\x89MCAP0\r\n"


@dataclass
class Recovered:
    """What :func:`scan_mcap` read: messages ``(topic, log time ns, data)`` and the losses."""

    path: Path
    size: int
    messages: list[tuple[str, int, bytes]] = field(default_factory=list)
    chunks: int = 0
    good_end: int = 0  # byte offset after the last record read
    complete: bool = False  # the data section ended properly (DataEnd or Footer)
    damage: str = ""  # why reading stopped early ('' when it did not)
    chunk_ends: list[tuple[int, int]] = field(default_factory=list)  # (end byte, messages)

    @property
    def lost_bytes(self) -> int:
        return 0 if self.complete else self.size - self.good_end

    def line(self) -> str:
        """One line: how much was read and what was left out."""
        span = ""
        if self.messages:
            t = [m[1] for m in self.messages]
            span = f", {(max(t) - min(t)) * 1e-9:.2f} s"
        read = f"read {self.chunks} complete chunk(s), {len(self.messages)} messages{span}"
        if self.complete:
            return f"{self.path}: its index and footer are missing or cut: {read}; none lost"
        why = f" ({self.damage})" if self.damage else ""
        lost = (
            f"lost its last {self.lost_bytes} of {self.size} bytes (a chunk cut short)"
            if self.lost_bytes
            else "it ends with a complete chunk (what came after was never written)"
        )
        return f"{self.path}: truncated bag (its recorder did not close it){why}: {read}; {lost}"


def cut_markers(markers: Sequence[Marker], last_ns: int, dt_ns: int) -> tuple[list[Marker], str]:
    """The segment markers a recovered bag can honour, and what its end cut short, in words.

    The recorder holds driver samples ``hold_s`` before writing them but writes the
    segment markers as they come, so a killed recorder's bag may hold the end marker
    of a segment whose last samples were never written. Markers after ``last_ns``
    (the last sample every driver topic has) are dropped: a segment cut short then has
    a start and no end and is left out, never read as if whole.
    """
    keep: list[Marker] = []
    for m in markers:
        t = round(m.t_s * 1e9)
        # a segment's last sample lies one period before its end marker
        limit = last_ns + dt_ns + dt_ns // 2 if m.event is MarkerEvent.END else last_ns
        if t <= limit:
            keep.append(m)
    ended = {(m.session, m.label) for m in keep if m.event is MarkerEvent.END}
    short = [
        repr(m.label)
        for m in keep
        if m.event is MarkerEvent.START and (m.session, m.label) not in ended
    ]
    starts = [m for m in keep if m.event is MarkerEvent.SESSION_START]
    if not starts:
        return keep, ""
    into = (last_ns - round(starts[-1].t_s * 1e9)) * 1e-9
    note = f"; its driver samples end {into:.2f} s into session {starts[-1].session}: "
    note += f"{len(ended)} complete segment(s)"
    if short:
        note += f", {', '.join(short)} cut short and left out"
    return keep, note


def _records(rec: Recovered, f: BinaryIO) -> None:
    """Every top-level record of ``f`` (mcap's ``StreamReader``) until the data section
    ends or the file does: messages of unchunked records and of each whole chunk kept,
    ``good_end`` moved past each record read. Raises where reading stops early."""
    from mcap.records import Channel, Chunk, DataEnd, Footer, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    topics: dict[int, str] = {}

    def keep(records: list) -> None:  # type: ignore[type-arg]
        for r in records:
            if isinstance(r, Channel):
                topics[r.id] = r.topic
            elif isinstance(r, Message) and r.channel_id in topics:
                rec.messages.append((topics[r.channel_id], r.log_time, r.data))

    for r in StreamReader(f, emit_chunks=True).records:
        if isinstance(r, (DataEnd, Footer)):
            rec.complete = True
            return
        if isinstance(r, Chunk):
            keep(breakup_chunk(r))  # decoded whole before any is kept: whole or not at all
            rec.chunks += 1
            rec.good_end = f.tell()
            rec.chunk_ends.append((rec.good_end, len(rec.messages)))
        else:
            keep([r])
            rec.good_end = f.tell()


def _cut_at(data: bytes, o: int) -> bool:
    """The record at byte ``o`` runs past the end of the file (cut, not damaged)."""
    if o + 9 > len(data):
        return True
    (n,) = struct.unpack_from("<Q", data, o + 1)
    return o + 9 + n > len(data)


def unfinished(path: Path) -> bool:
    """True when an MCAP file lacks its closing magic (never closed, or cut short)."""
    try:
        size = path.stat().st_size
        with path.open("rb") as f:
            f.seek(max(0, size - len(MAGIC)))
            return size < 2 * len(MAGIC) or f.read() != MAGIC
    except OSError:
        return True


def scan_mcap(path: str | Path) -> Recovered:
    """Every complete chunk of an MCAP file, however it ends (see the module doc)."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except OSError as exc:
        msg = f"{p}: not a readable rosbag2/MCAP bag ({exc.strerror or exc})"
        raise DataError(msg) from None
    rec = Recovered(p, len(data), good_end=min(len(data), len(MAGIC)))
    if data[: len(MAGIC)] != MAGIC:
        what = "an empty file" if not data else "no MCAP magic at its start"
        msg = f"{p}: not a readable rosbag2/MCAP bag ({what})"
        raise DataError(msg)
    try:
        with io.BytesIO(data) as f:
            _records(rec, f)
    except Exception as exc:  # noqa: BLE001 - any damage: keep what came before, say why
        if not _cut_at(data, rec.good_end):
            why = str(exc).strip() or type(exc).__name__
            rec.damage = f"damaged record at byte {rec.good_end}: {why}"[:200]
    return rec
