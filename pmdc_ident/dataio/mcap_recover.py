"""The readable part of an MCAP file that was never closed (recorder killed, disk full, cut copy).

A bag's ``.mcap`` gets its index and footer only when the recorder closes it; a
killed recorder leaves the data section alone, cut anywhere. The recorder closes
a chunk at least every half second, so everything but the last moments sits in
complete chunks. :func:`scan_mcap` walks the records from the start (the format:
https://mcap.dev/spec), keeps every complete chunk (and unchunked record) and
stops at the first record that does not fit in the file or does not parse. It
returns the messages with their topics and what was left out; any damage is
a :class:`~pmdc_ident.core.errors.DataError` with one line, never another exception.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from pmdc_ident.core.errors import DataError
from pmdc_ident.core.session import Marker, MarkerEvent

__all__ = ["Recovered", "cut_markers", "scan_mcap", "unfinished"]

MAGIC = b"\x89MCAP0\r\n"
_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK = 1, 2, 3, 4, 5, 6
_OP_DATA_END = 0x0F
_U16 = struct.Struct("<H")
_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_MSG_HEAD = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time


class _DamagedError(Exception):
    """A record that is complete in length but does not parse."""


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


def _string(b: memoryview, o: int) -> tuple[str, int]:
    (n,) = _U32.unpack_from(b, o)
    end = o + 4 + n
    if end > len(b):
        raise _DamagedError("string past its record")
    return bytes(b[o + 4 : end]).decode("utf-8"), end


class _Scanner:
    def __init__(self, rec: Recovered) -> None:
        self.rec = rec
        self.channels: dict[int, str] = {}  # channel id -> topic

    def records(self, b: memoryview, o: int, end: int, top: bool) -> int:
        """Parse the records of ``b[o:end]``; returns where the last complete one ended."""
        while o < end:
            if o + 9 > end:
                if top:
                    return o
                raise _DamagedError("a record cut inside its chunk")
            op = b[o]
            (n,) = _U64.unpack_from(b, o + 1)
            body, nxt = o + 9, o + 9 + n
            if nxt > end:
                if top:
                    return o
                raise _DamagedError("a record longer than its chunk")
            if top and op in (_OP_DATA_END, _OP_FOOTER):
                self.rec.complete = True
                return o
            self.record(op, b[body:nxt], top)
            o = nxt
            if top:
                self.rec.good_end = o
                if op == _OP_CHUNK:
                    self.rec.chunk_ends.append((o, len(self.rec.messages)))
        return o

    def record(self, op: int, r: memoryview, top: bool) -> None:
        if op == _OP_CHANNEL:
            (cid,) = _U16.unpack_from(r, 0)
            topic, _ = _string(r, 4)
            self.channels[cid] = topic
        elif op == _OP_MESSAGE:
            cid, _, log_ns, _ = _MSG_HEAD.unpack_from(r, 0)
            topic = self.channels.get(cid)
            if topic is not None:
                self.rec.messages.append((topic, log_ns, bytes(r[_MSG_HEAD.size :])))
        elif op == _OP_CHUNK and top:
            self.chunk(r)
        elif op == _OP_CHUNK:
            raise _DamagedError("a chunk inside a chunk")

    def chunk(self, r: memoryview) -> None:
        from rosbags.rosbag2.storage_mcap import decompress

        _, _, raw_size = struct.unpack_from("<QQQ", r, 0)
        (crc,) = _U32.unpack_from(r, 24)
        compression, o = _string(r, 28)
        (n,) = _U64.unpack_from(r, o)
        if o + 8 + n > len(r):
            raise _DamagedError("chunk data past its record")
        data = bytes(r[o + 8 : o + 8 + n])
        if compression:
            data = decompress(data, compression, raw_size, crc)
        inner = memoryview(data)
        before = len(self.rec.messages)
        try:
            self.records(inner, 0, len(inner), top=False)
        except Exception:
            del self.rec.messages[before:]  # a chunk counts whole or not at all
            raise
        self.rec.chunks += 1


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
    scanner = _Scanner(rec)
    try:
        scanner.records(memoryview(data), len(MAGIC), len(data), top=True)
    except Exception as exc:  # noqa: BLE001 - any damage: keep what came before, say why
        rec.damage = f"damaged record at byte {rec.good_end}: {exc}"[:200]
    return rec
