"""rosbag2/MCAP reading and writing without ROS (the ``rosbags`` library, ROS 2 Jazzy types).

What a session bag holds (topic names are matched by their last component, so a
namespaced graph works too):

=====================  ==========================  ======================================
topic                  type                        content
=====================  ==========================  ======================================
``current``            sensor_msgs/msg/JointState  effort[0] armature current, A
``encoder``            sensor_msgs/msg/JointState  position[0] rad, velocity[0] rad/s
``voltage_applied``    sensor_msgs/msg/JointState  effort[0] applied V (NaN: armature
                                                   open), effort[1] terminal V if measured
``voltage_cmd``        std_msgs/msg/Float64        the identification node's command, V
``segment``            std_msgs/msg/String         JSON segment marker
                                                   (:class:`pmdc_ident.core.markers.Marker`)
=====================  ==========================  ======================================

Driver topics carry the driver's own sample time in ``header.stamp``;
:func:`read_bag` joins them on that stamp and cuts the session's segments at the
markers' driver times (``start <= t < end``). The identification node builds its
online :class:`Run` with the same :func:`assemble_run`, so offline and online
identification see the same samples.
"""

from __future__ import annotations

import logging
import math
import struct
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Run, Segment, link_history
from pmdc_ident.core.errors import DataError, PmdcError
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.markers import Marker, MarkerEvent
from pmdc_ident.core.samples import DriverSamples
from pmdc_ident.core.stream_join import join_driver_samples

__all__ = [
    "BagWriter",
    "RecordingState",
    "TOPIC_TYPES",
    "assemble_run",
    "header_stamp_ns",
    "parse_joint_state",
    "read_bag",
    "read_driver_arrays",
    "recording_state",
    "write_bag",
]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

JOINT_STATE = "sensor_msgs/msg/JointState"
FLOAT64 = "std_msgs/msg/Float64"
STRING = "std_msgs/msg/String"
TOPIC_TYPES: dict[str, str] = {
    "current": JOINT_STATE,
    "encoder": JOINT_STATE,
    "voltage_applied": JOINT_STATE,
    "voltage_cmd": FLOAT64,
    "segment": STRING,
}
_STAMP = struct.Struct("<iI")
_log = logging.getLogger("pmdc_ident.bag")


def _typestore():  # type: ignore[no-untyped-def]
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def header_stamp_ns(cdr: bytes | memoryview) -> int:
    """``header.stamp`` in ns of a little-endian CDR message that starts with a Header."""
    if len(cdr) < 12 or cdr[1] != 1:
        msg = "not a little-endian CDR message with a header"
        raise DataError(msg)
    sec, nsec = _STAMP.unpack_from(cdr, 4)
    return sec * 1_000_000_000 + nsec


_U32 = struct.Struct("<I")
_F64 = struct.Struct("<d")
_NAN = math.nan


def parse_joint_state(cdr: bytes | memoryview) -> tuple[int, float, float, float, float]:
    """(stamp ns, position[0], velocity[0], effort[0], effort[1]) of a raw JointState.

    Decodes little-endian CDR directly (missing entries are NaN). Kept beside
    ``rosbags``' ``deserialize_cdr`` because that costs time: per message 1.2 us
    against 5.6 us (4.9x, docs/results.md), which the identification node pays at
    3 kHz; reading a ``make demo`` bag through ``rosbags``' reader, 0.63 s of CPU
    with this decode against 1.57 s with the library's (2.5x,
    ``benchmarks/bench_bag_read.py``, second reads).
    """
    b = cdr
    if len(b) < 16 or b[1] != 1:
        msg = "not a little-endian CDR JointState"
        raise DataError(msg)
    sec, nsec = _STAMP.unpack_from(b, 4)
    o = 8  # offsets relative to the payload (after the 4-byte encapsulation)
    (n,) = _U32.unpack_from(b, 4 + o)
    o += 4 + n
    o = (o + 3) & ~3
    (count,) = _U32.unpack_from(b, 4 + o)
    o += 4
    for _ in range(count):
        o = (o + 3) & ~3
        (n,) = _U32.unpack_from(b, 4 + o)
        o += 4 + n
    out = [_NAN, _NAN, _NAN, _NAN]
    for field_no in range(3):
        o = (o + 3) & ~3
        (count,) = _U32.unpack_from(b, 4 + o)
        o += 4
        if count:
            o = (o + 7) & ~7
            out[field_no] = _F64.unpack_from(b, 4 + o)[0]
            if field_no == 2 and count > 1:
                out[3] = _F64.unpack_from(b, 4 + o + 8)[0]
            o += 8 * count
    return sec * 1_000_000_000 + nsec, out[0], out[1], out[2], out[3]


# ---------------------------------------------------------------------------
# Assembling a Run from the driver topics
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class RecordingState:
    """How whole a recording is: what :func:`assemble_run` read and what it left out.

    ``interrupted``: why the session did not end normally ('' when it did);
    ``truncated``: the file was cut (its recorder never closed it) - what was lost;
    ``left_out``: segments cut short (a start marker without an end), never read;
    ``join``: how the topics were joined (a topic at another rate, samples missing on
    one topic). ``complete`` is True only when none of these applies.
    """

    source: str
    segments: tuple[str, ...]
    left_out: tuple[str, ...] = ()
    interrupted: str = ""
    truncated: str = ""
    join: tuple[str, ...] = ()
    missing_samples: int = 0

    @property
    def complete(self) -> bool:
        return not (self.interrupted or self.truncated or self.left_out or self.missing_samples)

    def lines(self, *, truncation: bool = True) -> list[str]:
        """One line per way the recording is not whole (none when it is). A truncated
        file's line says it all (where the samples end, what was cut short); the
        reader also logs it (``pmdc_ident.bag``): ``truncation=False`` leaves it out."""
        out = []
        if self.truncated:
            out += [self.truncated] if truncation else []
        elif self.interrupted:
            out.append(f"{self.source}: the session was interrupted ({self.interrupted})")
        if self.left_out and not self.truncated:
            out.append(
                f"{self.source}: segment(s) {', '.join(repr(s) for s in self.left_out)} "
                "cut short: left out (not fitted, checked or exported)"
            )
        out += [f"{self.source}: {j}" for j in self.join]
        return out

    def to_json(self) -> dict[str, Any]:
        return {
            "complete": self.complete,
            "interrupted": self.interrupted or None,
            "truncated": self.truncated or None,
            "segments": list(self.segments),
            "segments_left_out": list(self.left_out),
            "missing_samples": self.missing_samples,
            "join": list(self.join),
        }


_STATES: dict[str, RecordingState] = {}


def recording_state(source: str | Path) -> RecordingState | None:
    """The :class:`RecordingState` of the last :func:`assemble_run` of ``source`` in this
    process (None for a source never assembled, such as a CSV file)."""
    return _STATES.get(_state_key(source))


def _state_key(source: str | Path) -> str:
    return str(Path(source)) if str(source) else ""


def assemble_run(arrays: DriverSamples, source: str = "", session: str | None = None) -> Run:
    """Join the driver topics on their stamps (:func:`pmdc_ident.core.stream_join.
    join_driver_samples`: the one joining policy) and cut the session's
    segments.

    With ``session`` given only that session's markers are used (default: every
    session in the data). Times are seconds from the first session start (or the
    first sample without markers). A segment cut short (its start marker without an
    end: an interrupted session, a truncated file) is left out, never read as data;
    when no segment is complete, nothing is: :class:`DataError`. What was read and
    what was left out is kept as the source's :func:`recording_state`.
    """
    joined = join_driver_samples(arrays, source)
    stamps, cols, join_notes, missing = joined.stamps, joined.columns, joined.notes, joined.missing
    pos, spd, volt, term, cur = (
        cols[k] for k in ("position", "speed", "voltage", "terminal", "current")
    )
    dt_ns = int(np.median(np.diff(stamps)))

    markers = [m for m in arrays.markers if session is None or m.session == session]
    if session is not None and not markers:
        present = sorted({m.session for m in arrays.markers if m.session})
        have = f"sessions in it: {', '.join(present)}" if present else "it has no session markers"
        msg = f"{source or 'data'}: no session {session!r} ({have})"
        raise DataError(msg)
    spans = _segment_spans(markers)
    starts = [m for m in markers if m.event is MarkerEvent.SESSION_START]
    t0_ns = _ns(starts[0].t_s) if starts else int(stamps[0])
    left_out = _cut_short(markers)
    interrupted = _interruption(markers, stamps, t0_ns)
    truncated = "; ".join(arrays.notes)
    if not spans:
        if starts or left_out:
            why = interrupted or truncated or "no segment end marker"
            cut = f"{', '.join(repr(s) for s in left_out)} cut short; " if left_out else ""
            msg = (
                f"{source or 'data'}: no complete segment in the recording ({cut}{why}): "
                "nothing to fit, check or export"
            )
            raise DataError(msg)
        spans = [("run", int(stamps[0]), int(stamps[-1]) + dt_ns)]
    segments: list[Segment] = []
    half = dt_ns // 2
    for label, a_ns, b_ns in spans:
        lo = int(np.searchsorted(stamps, a_ns - half, side="left"))
        hi = int(np.searchsorted(stamps, b_ns - half, side="left"))
        if hi - lo < 2:
            left_out.append(label)
            continue
        sl = slice(lo, hi)
        tv = None
        if term is not None and np.isfinite(term[sl]).all():
            tv = term[sl]
        try:
            seg = Segment(
                label=label,
                t=(stamps[sl] - t0_ns) * 1e-9,
                voltage=volt[sl],
                current=None if cur is None else cur[sl],
                position=None if pos is None else pos[sl],
                speed=None if spd is None else spd[sl],
                terminal_voltage=tv,
            )
        except DataError as exc:
            msg = f"{source or 'data'}: {exc}"
            raise DataError(msg) from None
        segments.append(seg)
    if not segments:
        msg = f"{source or 'data'}: no segment holds 2 or more driver samples"
        raise DataError(msg)
    _STATES[_state_key(source)] = RecordingState(
        source=source or "data",
        segments=tuple(s.label for s in segments),
        left_out=tuple(left_out),
        interrupted=interrupted,
        truncated=truncated,
        join=tuple(join_notes),
        missing_samples=missing,
    )
    return Run(link_history(segments), source)


def _cut_short(markers: Sequence[Marker]) -> list[str]:
    """Segments whose start marker has no end marker (in time order)."""
    ended = {(m.session, m.label) for m in markers if m.event is MarkerEvent.END}
    return [
        m.label
        for m in sorted(markers, key=lambda m: m.t_s)
        if m.event is MarkerEvent.START and (m.session, m.label) not in ended
    ]


def _interruption(markers: Sequence[Marker], stamps: IntArray, t0_ns: int) -> str:
    """Why a session in ``markers`` did not end normally, or ''."""
    out = []
    for m in markers:
        if m.event is MarkerEvent.ABORT:
            out.append(f"session {m.session} aborted: {m.detail or 'no reason given'}")
    ended = {m.session for m in markers if m.event is MarkerEvent.SESSION_END}
    for m in markers:
        if m.event is MarkerEvent.SESSION_START and m.session not in ended:
            into = (int(stamps[-1]) - t0_ns) * 1e-9
            out.append(f"session {m.session} has no end marker: its samples stop {into:.2f} s in")
    return "; ".join(out)


def _ns(t_s: float) -> int:
    return int(round(t_s * 1e9))


def _segment_spans(markers: Sequence[Marker]) -> list[tuple[str, int, int]]:
    """(label, start ns, end ns) from START/END marker pairs, in time order."""
    open_: dict[tuple[str, str], int] = {}
    spans: list[tuple[str, int, int]] = []
    for m in sorted(markers, key=lambda m: m.t_s):
        key = (m.session, m.label)
        if m.event is MarkerEvent.START:
            open_[key] = _ns(m.t_s)
        elif m.event is MarkerEvent.END and key in open_:
            spans.append((m.label, open_.pop(key), _ns(m.t_s)))
    return sorted(spans, key=lambda s: s[1])


# ---------------------------------------------------------------------------
# Reading
# ---------------------------------------------------------------------------
def _topic_role(topic: str) -> str | None:
    last = topic.rstrip("/").rsplit("/", 1)[-1]
    return last if last in TOPIC_TYPES else None


def read_driver_arrays(path: str | Path) -> DriverSamples:
    """The driver topics and segment markers of a bag directory or ``.mcap`` file.

    A bag its recorder never closed (killed, power cut, a copy cut short) has no
    ``metadata.yaml``, index or footer: its complete chunks are read
    (:func:`pmdc_ident.dataio.mcap_recover.scan_mcap`) and one line on the
    ``pmdc_ident.bag`` logger says what was lost. rosbags (~20 ms of imports) is
    imported only when the compiled MCAP scan cannot read the bag.
    """
    p = Path(path)
    if p.is_dir() and not (p / "metadata.yaml").is_file():
        inside = sorted(p.glob("*.mcap"))
        if len(inside) == 1:  # what a killed recorder leaves
            from pmdc_ident.dataio.mcap_recover import unfinished

            if unfinished(inside[0]):
                return _recovered_arrays(p, inside[0])
            _log.warning(f"{p}: no metadata.yaml: read {inside[0].name}, a complete MCAP file")
            return read_driver_arrays(inside[0])
        csvs = sorted(f.name for f in p.iterdir() if f.suffix.lower() in (".csv", ".txt"))
        if len(inside) > 1:
            msg = (
                f"{p}: {len(inside)} .mcap files and no metadata.yaml: not one bag; pass one "
                f"file ({p / inside[0].name}), or {opt('batch')} OUTDIR to treat each on its own"
            )
        elif csvs:
            msg = (
                f"{p}: a folder of CSV files ({', '.join(csvs[:3])}{', ...' * (len(csvs) > 3)}), "
                f"not a bag: pass the files themselves, or {opt('batch')} OUTDIR to treat each on "
                "its own"
            )
        else:
            msg = (
                f"{p}: a folder without metadata.yaml or an .mcap file: not a rosbag2 bag "
                "(give a bag folder, an .mcap file or a CSV file)"
            )
        raise DataError(msg)
    fast = _read_driver_arrays_fast(p)
    if fast is not None:
        return fast
    from rosbags.rosbag2 import Reader

    try:
        with Reader(p) as reader:
            conns = [c for c in reader.connections if _topic_role(c.topic)]
            _check_types(p, conns)
            messages = [(c.topic, raw) for c, _, raw in reader.messages(connections=conns)]
            topics = sorted(c.topic for c in reader.connections)
    except DataError:
        raise
    except Exception as exc:  # noqa: BLE001 - whatever rosbags raises on a damaged bag
        from pmdc_ident.dataio.mcap_recover import unfinished

        mcap = _mcap_files(p) if p.is_file() else sorted(p.glob("*.mcap"))
        # an MCAP never closed (or cut short) is read up to its last complete chunk
        if not mcap or len(mcap) != 1 or not unfinished(mcap[0]):
            first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            msg = f"{p}: not a readable rosbag2/MCAP bag ({first})"
            raise DataError(msg) from None
        return _recovered_arrays(p, mcap[0])
    return _arrays_from(p, messages, topics)


def _check_types(p: Path, conns: Sequence[Any]) -> None:
    """Each driver topic holds the message type the driver publishes (a TwistStamped
    encoder was read as a JointState and reported as 'neither position nor speed')."""
    for c in conns:
        role = _topic_role(c.topic)
        want = TOPIC_TYPES.get(role or "")
        if want is not None and c.msgtype != want:
            what = {
                "encoder": "position[0] rad, velocity[0] rad/s",
                "current": "effort[0] A",
                "voltage_applied": "effort[0] V, NaN while open",
            }.get(role or "", "")
            msg = (
                f"{p}: topic {c.topic} is {c.msgtype}; pmdc_ident reads {want} there"
                f"{f' ({what})' if what else ''}, as the driver node publishes it: republish "
                "it in that type, or export the samples as CSV (t, voltage, current, "
                "position/speed)"
            )
            raise DataError(msg)


def _recovered_arrays(p: Path, mcap: Path) -> DriverSamples:
    """The driver topics in the complete chunks of ``mcap``; one line says what was lost."""
    from pmdc_ident.dataio.mcap_recover import cut_markers, scan_mcap

    rec = scan_mcap(mcap)
    if not rec.messages:
        msg = (
            f"{p}: not a readable rosbag2/MCAP bag (cut before its first complete chunk, "
            f"at byte {rec.good_end} of {rec.size})"
        )
        raise DataError(msg)
    messages = [(topic, raw) for topic, _, raw in rec.messages if _topic_role(topic)]
    if not any(_topic_role(t) in ("encoder", "current", "voltage_applied") for t, _ in messages):
        msg = (
            f"{p}: truncated bag (its recorder did not close it) whose complete chunks hold "
            f"no driver sample (cut at byte {rec.good_end} of {rec.size}): nothing to read"
        )
        raise DataError(msg)
    arrays = _arrays_from(p, messages)
    ends = [a[-1] for a in (arrays.encoder_ns, arrays.voltage_ns, arrays.current_ns) if a.size]
    note = ""
    markers = arrays.markers
    if ends and arrays.encoder_ns.size > 1:
        dt_ns = int(np.median(np.diff(arrays.encoder_ns)))
        kept, note = cut_markers(markers, int(min(ends)), dt_ns)
        markers = tuple(kept)
    _log.warning(rec.line() + note)
    return replace(arrays, markers=markers, notes=(*arrays.notes, rec.line() + note))


def _arrays_from(
    p: Path, messages: list[tuple[str, bytes]], topics: list[str] | None = None
) -> DriverSamples:
    """DriverSamples from (topic, CDR) pairs of the driver topics and the markers."""
    roles = (
        {_topic_role(t) for t, _ in messages} if topics is None else set(map(_topic_role, topics))
    )
    for need in ("encoder", "voltage_applied"):
        if need not in roles:
            names = sorted(topics if topics is not None else {t for t, _ in messages})
            msg = f"{p}: no '{need}' topic in the bag (topics: {', '.join(names)})"
            raise DataError(msg)
    ts = _typestore()
    cols: dict[str, list[Any]] = {k: [] for k in ("cur", "enc", "volt")}
    markers: list[Marker] = []
    try:
        for topic, raw in messages:
            role = _topic_role(topic)
            if role == "segment":
                text = ts.deserialize_cdr(raw, STRING).data
                try:
                    markers.append(Marker.from_json(text))
                except PmdcError:
                    continue
                continue
            if role == "voltage_cmd":
                continue
            stamp, pos, vel, e0, e1 = parse_joint_state(raw)
            if role == "current":
                cols["cur"].append((stamp, e0))
            elif role == "encoder":
                cols["enc"].append((stamp, pos, vel))
            else:
                cols["volt"].append((stamp, e0, e1))
    except (KeyError, struct.error, DataError, ValueError, IndexError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
        msg = f"{p}: not a readable rosbag2/MCAP bag ({first})"
        raise DataError(msg) from None

    def arr(rows: list[Any], n: int) -> tuple[IntArray, NDArray[Any]]:
        # stamps stay integers: as float64 seconds-since-1970 they would lose ~0.2 us
        stamps = np.array([r[0] for r in rows], dtype=np.int64)
        values = np.array([r[1:] for r in rows], dtype=float).reshape(-1, n - 1)
        return stamps, values

    (cur_ns, cur), (enc_ns, enc), (volt_ns, volt) = (
        arr(cols["cur"], 2),
        arr(cols["enc"], 3),
        arr(cols["volt"], 3),
    )
    return _driver_arrays(
        (cur_ns, cur[:, 0]),
        (enc_ns, enc[:, 0], enc[:, 1]),
        (volt_ns, volt[:, 0], volt[:, 1]),
        markers,
    )


def _driver_arrays(
    current: tuple[IntArray, FloatArray],
    encoder: tuple[IntArray, FloatArray, FloatArray],
    voltage: tuple[IntArray, FloatArray, FloatArray],
    markers: list[Marker],
) -> DriverSamples:
    """DriverSamples from (stamps, values...) per topic: NaN-holding encoder columns are absent."""
    enc_ns, pos, vel = encoder
    volt_ns, volt, term = voltage
    return DriverSamples(
        current_ns=current[0],
        current_a=current[1],
        encoder_ns=enc_ns,
        position_rad=pos if pos.size and np.isfinite(pos).all() else None,
        speed_rad_s=vel if vel.size and np.isfinite(vel).all() else None,
        voltage_ns=volt_ns,
        voltage_v=volt,
        terminal_v=term if term.size and np.isfinite(term).any() else None,
        markers=tuple(markers),
    )


def _mcap_files(p: Path) -> list[Path] | None:
    """The MCAP files of a bag directory or an ``.mcap`` path; None for other storage."""
    if p.is_file():
        return [p] if p.suffix.lower() == ".mcap" else None
    meta = p / "metadata.yaml"
    if not meta.is_file():
        return None
    import yaml

    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        if info.get("storage_identifier") != "mcap" or info.get("compression_format"):
            return None
        files = [p / f for f in info["relative_file_paths"]]
    except (yaml.YAMLError, KeyError, TypeError, UnicodeDecodeError):
        return None
    return files if files and all(f.is_file() for f in files) else None


def _read_driver_arrays_fast(p: Path) -> DriverSamples | None:
    """read_driver_arrays by one compiled pass over complete MCAP files (mcap_scan), or None.

    None (the caller then reads with rosbags) for other storage, unfinished or
    compressed files, missing driver topics and anything else the scan does not read.
    """
    from pmdc_ident.dataio import mcap_scan as ms

    files = _mcap_files(p)
    if files is None:
        return None
    try:
        scan = ms.scan_driver_topics(files)
    except ValueError as exc:
        msg = f"{p}: not a readable rosbag2/MCAP bag ({exc})"
        raise DataError(msg) from None
    if scan is None or not {ms.ROLE_ENCODER, ms.ROLE_VOLTAGE} <= scan.roles:
        return None
    markers = []
    for text in scan.segment_texts:
        try:
            markers.append(Marker.from_json(text))
        except PmdcError:
            continue
    cur, enc, volt = (scan.values[r] for r in (ms.ROLE_CURRENT, ms.ROLE_ENCODER, ms.ROLE_VOLTAGE))
    return _driver_arrays(
        (scan.stamps[ms.ROLE_CURRENT], cur[:, 2]),
        (scan.stamps[ms.ROLE_ENCODER], enc[:, 0], enc[:, 1]),
        (scan.stamps[ms.ROLE_VOLTAGE], volt[:, 2], volt[:, 3]),
        markers,
    )


def read_bag(path: str | Path, session: str | None = None) -> Run:
    """A recorded session (bag directory or ``.mcap`` file) as a :class:`Run`."""
    from pmdc_ident.core.safe_write import protect

    p = Path(path)
    if not p.exists():
        msg = f"{p}: no such bag"
        raise DataError(msg)
    protect([p])
    return assemble_run(read_driver_arrays(p), source=str(p), session=session)


# ---------------------------------------------------------------------------
# Writing
# ---------------------------------------------------------------------------
class BagWriter:
    """A rosbag2 (MCAP storage) writer for the session topics; a context manager.

    ``write_raw`` takes CDR bytes as rclpy delivers them with ``raw=True``;
    ``write_msg`` serializes a rosbags message object. The pending chunk is closed
    and handed to the operating system every ``flush_s`` (and on :meth:`flush`),
    so a writer killed mid-session leaves every chunk but the last one readable
    (:func:`read_bag` recovers them).
    """

    def __init__(self, path: str | Path, topics: dict[str, str], flush_s: float = 0.5) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.path = Path(path)
        if self.path.exists():
            msg = f"{self.path}: exists already; a bag is never overwritten"
            raise DataError(msg)
        self.typestore = _typestore()
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._topics = dict(topics)
        self._conns: dict[str, Any] = {}
        self.counts: dict[str, int] = {}
        self.is_open = False
        self.flush_s = float(flush_s)
        self._next_flush = 0.0

    def open(self) -> BagWriter:
        self._writer.open()
        for topic, msgtype in self._topics.items():
            self._conns[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self.typestore
            )
            self.counts[topic] = 0
        self.is_open = True
        return self

    def __enter__(self) -> BagWriter:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def write_raw(self, topic: str, timestamp_ns: int, data: bytes | memoryview) -> None:
        self._writer.write(self._conns[topic], int(timestamp_ns), data)
        self.counts[topic] += 1
        if time.monotonic() >= self._next_flush:
            self.flush()

    def flush(self) -> None:
        """Close the pending chunk (if it holds messages) and write it to the file."""
        self._next_flush = time.monotonic() + self.flush_s
        storage = getattr(self._writer, "storage", None)  # rosbags' MCAP writer (pinned)
        if storage is None or not self.is_open:
            return
        if storage.chunk.msgs:
            storage.close_chunk()
        storage.bio.flush()

    def set_custom_data(self, key: str, value: str) -> None:
        """A ``custom_data`` entry of ``metadata.yaml`` (written at :meth:`close`)."""
        self._writer.set_custom_data(key, value)

    def write_msg(self, topic: str, timestamp_ns: int, msg: Any) -> None:
        data = self.typestore.serialize_cdr(msg, self._topics[topic])
        self.write_raw(topic, timestamp_ns, data)

    def close(self) -> None:
        if self.is_open:
            self.is_open = False
            self._writer.close()


def _joint_state(ts: Any, stamp_ns: int, name: list[str], **arrays: Iterable[float]) -> Any:
    JS = ts.types[JOINT_STATE]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    sec, nsec = divmod(int(stamp_ns), 1_000_000_000)
    empty = np.zeros(0)
    return JS(
        header=Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=""),
        name=name,
        position=np.asarray(list(arrays.get("position", empty)), dtype=float),
        velocity=np.asarray(list(arrays.get("velocity", empty)), dtype=float),
        effort=np.asarray(list(arrays.get("effort", empty)), dtype=float),
    )


def write_bag(run: Run, path: str | Path, session: str = "export", flush_s: float = 0.5) -> Path:
    """Write a Run as a session bag (driver topics + segment markers) that read_bag reads.

    Segments whose times do not follow the previous one are shifted to start one
    sample period after it, so the bag keeps one increasing driver clock. The bag is
    written under a temporary name and appears under ``path`` only once closed
    (:func:`pmdc_ident.core.safe_write.atomic_folder`): an interrupted export leaves
    no bag that looks complete.
    """
    from pmdc_ident.core.safe_write import atomic_folder

    final = Path(path)
    with atomic_folder(final) as tmp:
        _write_bag(run, tmp, session, flush_s)
    return final


def _write_bag(run: Run, p: Path, session: str, flush_s: float) -> None:
    offset = 0.0
    last_t = -math.inf
    topics = {k: v for k, v in TOPIC_TYPES.items() if k != "voltage_cmd"}
    with BagWriter(p, topics, flush_s=flush_s) as w:
        ts = w.typestore
        String = ts.types[STRING]
        first = True
        for seg in run.segments:
            t = seg.t + offset
            if t[0] <= last_t:
                shift = last_t + seg.dt_s - t[0]
                offset += shift
                t = t + shift
            if t[0] < 0:  # the driver clock is never negative
                offset -= t[0]
                t = t - t[0]
            stamps = np.round(t * 1e9).astype(np.int64)
            end_ns = int(stamps[-1]) + int(round(seg.dt_s * 1e9))
            events = []
            if first:  # the session starts at driver time 0: read_bag gives back seg.t
                events.append(Marker(MarkerEvent.SESSION_START, "", 0.0, session))
                first = False
            events.append(Marker(MarkerEvent.START, seg.label, stamps[0] * 1e-9, session))
            for m in events:
                w.write_msg("segment", int(stamps[0]), String(data=m.to_json()))
            speed = seg.speed
            pos = seg.position if seg.position is not None else np.full(seg.n, math.nan)
            volt = seg.voltage if seg.voltage is not None else np.full(seg.n, math.nan)
            for k in range(seg.n):
                s = int(stamps[k])
                if seg.current is not None:
                    w.write_msg(
                        "current", s, _joint_state(ts, s, ["armature"], effort=[seg.current[k]])
                    )
                enc: dict[str, list[float]] = {"position": [pos[k]]}
                if speed is not None:
                    enc["velocity"] = [speed[k]]
                w.write_msg("encoder", s, _joint_state(ts, s, ["shaft"], **enc))
                eff = [volt[k]]
                names = ["armature"]
                if seg.terminal_voltage is not None:
                    eff.append(seg.terminal_voltage[k])
                    names.append("terminal")
                w.write_msg("voltage_applied", s, _joint_state(ts, s, names, effort=eff))
            end = Marker(MarkerEvent.END, seg.label, end_ns * 1e-9, session)
            w.write_msg("segment", end_ns, String(data=end.to_json()))
            last_t = float(t[-1])
        done = Marker(MarkerEvent.SESSION_END, "", end_ns * 1e-9, session)
        w.write_msg("segment", end_ns, String(data=done.to_json()))
