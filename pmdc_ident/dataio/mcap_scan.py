"""The driver topics of MCAP files in one compiled pass over the records.

A 60 s session at 1 kHz holds 180 000 JointState messages. Reading them through
``rosbags`` (a time-ordered merge of Python message tuples, then one CDR decode
per message) costs about a second of CPU; this module walks the MCAP records
with numba kernels instead, decodes the JointState fields that
:func:`pmdc_ident.dataio.bagio.parse_joint_state` decodes, the same way, and
hands back the per-topic columns in log-time order, as ``rosbags`` yields them.

It reads what it fully understands - complete MCAP files (magic at both ends)
with uncompressed, zstd or lz4 chunks, CDR-encoded channels of the expected types
- and returns ``None`` for anything else (a sqlite3 bag, a file still being
written or cut short, a compressed bag file, an unknown topic type), so that the
caller falls back to the general ``rosbags`` reader and its error messages.

Kept because the libraries cost the user time (``benchmarks/bench_bag_read.py`` on
a ``make demo`` bag, 13.9 MB, 117 756 driver messages, CPU seconds, best of 3 fresh
processes, measured on 1cbb874): the first read in a fresh process, numba's import and
cache included, 0.69 s against 0.89 s for ``rosbags``' reader with our CDR decode
(1.3x), 1.72 s for ``rosbags`` alone (2.5x), 2.87 s for ``mcap`` + ``rosbags``' CDR
(4.2x), 3.25 s for ``mcap`` + ``mcap_ros2`` (4.7x); a second read (numba loaded, as
``identify`` has it for the fit anyway) 0.061 s against 0.63 s (10x) and 1.57 s (26x).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core._jit import njit

__all__ = ["MAGIC", "ScanResult", "scan_driver_topics"]

MAGIC = b"\x89MCAP0\r\n"
OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 3, 4, 5, 6

# roles of a channel, by the last component of its topic
ROLE_NONE, ROLE_CURRENT, ROLE_ENCODER, ROLE_VOLTAGE, ROLE_SEGMENT = 0, 1, 2, 3, 4
_JOINT_STATE_ROLES = {"current": ROLE_CURRENT, "encoder": ROLE_ENCODER}
_JOINT_STATE_ROLES["voltage_applied"] = ROLE_VOLTAGE
JOINT_STATE = "sensor_msgs/msg/JointState"
STRING = "std_msgs/msg/String"


@njit
def _u64(b, o):  # pragma: no cover - jitted
    v = np.int64(0)
    for k in range(7, -1, -1):
        v = (v << 8) | np.int64(b[o + k])
    return v


@njit
def _u32(b, o):  # pragma: no cover - jitted
    return (
        np.int64(b[o])
        | (np.int64(b[o + 1]) << 8)
        | (np.int64(b[o + 2]) << 16)
        | (np.int64(b[o + 3]) << 24)
    )


@njit
def _walk(buf, lo, hi, count_only, ops, offs, lens):  # pragma: no cover - jitted
    """Records in ``buf[lo:hi]``: opcode, content offset, content length; their count.

    -1 when a record runs past ``hi`` (a truncated file or chunk).
    """
    n = 0
    o = lo
    while o < hi:
        if o + 9 > hi:
            return -1
        length = _u64(buf, o + 1)
        if length < 0 or o + 9 + length > hi:
            return -1
        if not count_only:
            ops[n] = buf[o]
            offs[n] = o + 9
            lens[n] = length
        n += 1
        o += 9 + length
    return n


@njit
def _joint_state(b, lo, hi, out):  # pragma: no cover - jitted
    """Decode one CDR JointState in ``b[lo:hi]`` as ``parse_joint_state``; False if malformed.

    ``out`` gets stamp sec, nsec, position[0], velocity[0], effort[0], effort[1]
    (NaN where an array is empty).
    """
    if hi - lo < 16 or b[lo + 1] != 1:
        return False
    p = lo + 4  # CDR alignment counts from the payload, after the encapsulation header
    sec = _u32(b, p)
    if sec >= 2**31:
        sec -= 2**32
    out[0] = sec
    out[1] = _u32(b, p + 4)
    o = 8
    if p + o + 4 > hi:
        return False
    o += 4 + _u32(b, p + o)  # frame_id
    o = (o + 3) & ~3
    if p + o + 4 > hi:
        return False
    count = _u32(b, p + o)
    o += 4
    for _ in range(count):  # names
        o = (o + 3) & ~3
        if p + o + 4 > hi:
            return False
        o += 4 + _u32(b, p + o)
    out[2:6] = np.nan
    for field in range(3):  # position, velocity, effort
        o = (o + 3) & ~3
        if p + o + 4 > hi:
            return False
        count = _u32(b, p + o)
        o += 4
        if count:
            o = (o + 7) & ~7
            n_read = 2 if field == 2 and count > 1 else 1
            if p + o + 8 * n_read > hi:
                return False
            for j in range(n_read):
                out[2 + field + j] = (
                    b[p + o + 8 * j : p + o + 8 * j + 8].copy().view(np.float64)[0]
                )
            o += 8 * count
    return True


@njit
def _messages(buf, offs, lens, roles, log_ns, role_of, stamp_ns, values):  # pragma: no cover
    """Decode the JointState messages among the MESSAGE records at ``offs``.

    Fills, per message, its log time, channel role, header stamp and the four
    values; returns the index of the first malformed message, or -1.
    """
    tmp = np.empty(6)
    for k in range(offs.size):
        o = offs[k]
        if lens[k] < 22:
            return k
        role = roles[np.int64(buf[o]) | (np.int64(buf[o + 1]) << 8)]
        role_of[k] = role
        log_ns[k] = _u64(buf, o + 6)
        if role == ROLE_CURRENT or role == ROLE_ENCODER or role == ROLE_VOLTAGE:
            if not _joint_state(buf, o + 22, o + lens[k], tmp):
                return k
            stamp_ns[k] = np.int64(tmp[0]) * 1_000_000_000 + np.int64(tmp[1])
            values[k, :] = tmp[2:6]
    return -1


def _records(buf: NDArray[np.uint8], lo: int, hi: int) -> tuple[NDArray, NDArray, NDArray] | None:
    n = _walk(
        buf, lo, hi, True, np.empty(0, np.uint8), np.empty(0, np.int64), np.empty(0, np.int64)
    )
    if n < 0:
        return None
    ops, offs, lens = np.empty(n, np.uint8), np.empty(n, np.int64), np.empty(n, np.int64)
    _walk(buf, lo, hi, False, ops, offs, lens)
    return ops, offs, lens


def _string(buf: NDArray[np.uint8], o: int) -> tuple[str, int]:
    n = int(buf[o : o + 4].view("<u4")[0])
    return bytes(buf[o + 4 : o + 4 + n]).decode("utf-8"), o + 4 + n


def _decompress(compression: str, data: bytes, size: int) -> bytes | None:
    if compression == "zstd":
        import zstandard

        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(data)
    return None


@dataclass
class _Buffer:
    """One byte buffer (a file or a decompressed chunk) and its MESSAGE records."""

    buf: NDArray[np.uint8]
    offs: NDArray[np.int64]
    lens: NDArray[np.int64]


@dataclass
class ScanResult:
    """Per-role columns in log-time order (``values``: position, velocity, effort[0..1])."""

    stamps: dict[int, NDArray[np.int64]]
    values: dict[int, NDArray[np.float64]]
    segment_texts: list[str]
    roles: set[int]  # roles that have a channel (with or without messages)


class _UnsupportedError(Exception):
    """Something this reader does not handle: the caller uses the general reader."""


def _file_buffers(path: Path, schemas: dict[int, str], channels: dict[int, tuple[str, int]]):
    """MESSAGE records of one file, chunk by chunk; schema and channel records noted."""
    buf = np.fromfile(path, dtype=np.uint8)
    if buf.size < 16 or bytes(buf[:8]) != MAGIC or bytes(buf[-8:]) != MAGIC:
        raise _UnsupportedError
    pending = [(buf, 8, buf.size - 8)]
    while pending:
        b, lo, hi = pending.pop(0)
        recs = _records(b, lo, hi)
        if recs is None:
            raise _UnsupportedError
        ops, offs, lens = recs
        for op, o in zip(ops.tolist(), offs.tolist(), strict=True):
            if op == OP_SCHEMA:
                sid = int(b[o]) | int(b[o + 1]) << 8
                schemas[sid] = _string(b, o + 2)[0]
            elif op == OP_CHANNEL:
                cid = int(b[o]) | int(b[o + 1]) << 8
                sid = int(b[o + 2]) | int(b[o + 3]) << 8
                topic, p = _string(b, o + 4)
                encoding, _ = _string(b, p)
                if encoding != "cdr":
                    raise _UnsupportedError
                channels[cid] = (topic, sid)
            elif op == OP_CHUNK:
                size = int(b[o + 16 : o + 24].view("<u8")[0])
                compression, p = _string(b, o + 28)
                n = int(b[p : p + 8].view("<u8")[0])
                if not compression:
                    pending.append((b, p + 8, p + 8 + n))
                    continue
                raw = _decompress(compression, bytes(b[p + 8 : p + 8 + n]), size)
                if raw is None:
                    raise _UnsupportedError
                # writable, as a file's buffer is: a read-only array (of bytes) is
                # another signature, and numba compiled the scan's five kernels
                # again for it (2.8 CPU-s) on the first compressed bag
                inner = np.frombuffer(bytearray(raw), dtype=np.uint8)
                pending.append((inner, 0, inner.size))
        is_msg = ops == OP_MESSAGE
        if is_msg.any():
            yield _Buffer(b, offs[is_msg], lens[is_msg])


def _roles(schemas: dict[int, str], channels: dict[int, tuple[str, int]]) -> NDArray[np.int8]:
    roles = np.zeros(65536, dtype=np.int8)
    for cid, (topic, sid) in channels.items():
        last = topic.rstrip("/").rsplit("/", 1)[-1]
        want = JOINT_STATE if last in _JOINT_STATE_ROLES else STRING if last == "segment" else None
        if want is None:
            continue
        if schemas.get(sid) != want:
            raise _UnsupportedError
        roles[cid] = _JOINT_STATE_ROLES.get(last, ROLE_SEGMENT)
    return roles


def scan_driver_topics(paths: list[Path]) -> ScanResult | None:
    """The driver topics of these MCAP files, or ``None`` when a file is not one this reads.

    Raises ``ValueError`` for a malformed JointState (the caller reports the bag).
    """
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, int]] = {}
    parts: list[tuple[NDArray, ...]] = []
    texts: list[tuple[int, str]] = []
    try:
        for path in paths:
            # channels precede their messages: roles are known once a file's records are walked
            buffers = list(_file_buffers(path, schemas, channels))
            roles = _roles(schemas, channels)
            for bb in buffers:
                n = bb.offs.size
                log_ns, role_of = np.empty(n, np.int64), np.empty(n, np.int8)
                stamp_ns, values = np.zeros(n, np.int64), np.full((n, 4), np.nan)
                bad = _messages(bb.buf, bb.offs, bb.lens, roles, log_ns, role_of, stamp_ns, values)
                if bad >= 0:
                    msg = "not a little-endian CDR JointState"
                    raise ValueError(msg)
                parts.append((log_ns, role_of, stamp_ns, values))
                for k in np.flatnonzero(role_of == ROLE_SEGMENT).tolist():
                    o = int(bb.offs[k]) + 22 + 4  # after the message header and CDR header
                    texts.append((int(log_ns[k]), _string(bb.buf, o)[0].rstrip("\x00")))
    except _UnsupportedError:
        return None
    present = {int(r) for r in np.unique(roles)} - {ROLE_NONE} if channels else set()
    if not parts:
        empty = np.zeros(0, np.int64), np.zeros((0, 4))
        return ScanResult(
            {r: empty[0] for r in (1, 2, 3)}, {r: empty[1] for r in (1, 2, 3)}, [], present
        )
    log_ns, role_of, stamp_ns, values = (np.concatenate(c) for c in zip(*parts, strict=True))
    order = np.argsort(log_ns, kind="stable")
    stamps, vals = {}, {}
    for role in (ROLE_CURRENT, ROLE_ENCODER, ROLE_VOLTAGE):
        sel = order[role_of[order] == role]
        stamps[role], vals[role] = stamp_ns[sel], values[sel]
    texts.sort(key=lambda t: t[0])
    return ScanResult(stamps, vals, [t for _, t in texts], present)
