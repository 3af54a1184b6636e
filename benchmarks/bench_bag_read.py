"""Reading a session bag: our MCAP/CDR code against the ``rosbags`` and ``mcap`` libraries.

``pmdc_ident/dataio`` holds two hand-written readers beside its library
dependencies: :mod:`~pmdc_ident.dataio.mcap_scan` (one compiled pass over the MCAP
records and the JointState CDR) and :func:`~pmdc_ident.dataio.bagio.parse_joint_state`
(the CDR decode behind ``rosbags``' reader on the general path). They stay only if
the libraries cost the user time; this script measures that on a real session bag,
by default the newest one ``make demo`` wrote (``pmdc_sessions/demo/``), each way
in a fresh process (what a ``pmdc-ident identify BAG`` pays: imports, numba's cache,
the read), then the second read in that process. Times are CPU seconds of the reading
process (user + system): on this shared 2-core machine wall times swing with the load,
CPU time much less (every way reads one file on one thread).

* ``ours``: :func:`~pmdc_ident.dataio.bagio.read_driver_arrays` as shipped (mcap_scan);
* ``rosbags + our CDR``: ``rosbags``' reader, our ``parse_joint_state`` (the general
  path, taken for sqlite3 or compressed bags);
* ``rosbags``: ``rosbags``' reader and its ``deserialize_cdr`` (libraries only);
* ``mcap + rosbags CDR``: the ``mcap`` reader's ``iter_messages``, ``rosbags``'
  ``deserialize_cdr``;
* ``mcap + mcap_ros2``: the ``mcap`` reader with ``mcap_ros2``'s decoder.

Every way must give the same per-topic stamps and values (checked; the script fails
otherwise). It prints the times and each one's ratio against ``ours``.

Then a bag its recorder never closed: the MCAP file cut at 40 % of its bytes, read
by :func:`~pmdc_ident.dataio.mcap_recover.scan_mcap` and by the ``mcap`` library's
``StreamReader`` (the one library reader that reads a file without its footer; the
others need the summary), CPU seconds and the messages each recovers. Run by hand
under ``nice``, never beside another benchmark::

    make demo   # once: writes a session bag under pmdc_sessions/demo/
    nice .venv/bin/python benchmarks/bench_bag_read.py [--bag BAG] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
WAYS = ("ours", "rosbags + our CDR", "rosbags", "mcap + rosbags CDR", "mcap + mcap_ros2")
ROLES = ("current", "encoder", "voltage_applied")


def _role(topic: str) -> str | None:
    last = topic.rstrip("/").rsplit("/", 1)[-1]
    return last if last in ROLES else None


def _columns(rows: dict[str, list]) -> dict[str, np.ndarray]:
    """Per role: stamps (ns) and (position, velocity, effort[0]) as one float array."""
    return {r: np.array(rows[r], dtype=float).reshape(-1, 4) for r in ROLES}


def _from_msg(msg) -> tuple[int, float, float, float]:  # noqa: ANN001
    first = lambda a: float(a[0]) if len(a) else np.nan  # noqa: E731
    stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
    return stamp, first(msg.position), first(msg.velocity), first(msg.effort)


def read_ours(bag: Path) -> dict[str, np.ndarray]:
    from pmdc_ident.dataio.bagio import read_driver_arrays

    a = read_driver_arrays(bag)
    nan = np.full(a.encoder_ns.size, np.nan)
    cols = {
        "current": (a.current_ns, nan[: a.current_ns.size], nan[: a.current_ns.size], a.current_a),
        "encoder": (a.encoder_ns, a.position_rad, a.speed_rad_s, nan),
        "voltage_applied": (
            a.voltage_ns,
            nan[: a.voltage_ns.size],
            nan[: a.voltage_ns.size],
            a.voltage_v,
        ),
    }
    return {r: np.column_stack([np.asarray(c, dtype=float) for c in v]) for r, v in cols.items()}


def read_rosbags(bag: Path, *, our_cdr: bool) -> dict[str, np.ndarray]:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from pmdc_ident.dataio.bagio import parse_joint_state

    ts = get_typestore(Stores.ROS2_JAZZY)
    rows: dict[str, list] = {r: [] for r in ROLES}
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if _role(c.topic)]
        for c, _, raw in reader.messages(connections=conns):
            if our_cdr:
                stamp, pos, vel, e0, _ = parse_joint_state(raw)
                rows[_role(c.topic)].append((stamp, pos, vel, e0))
            else:
                rows[_role(c.topic)].append(_from_msg(ts.deserialize_cdr(raw, c.msgtype)))
    return _columns(rows)


def read_mcap(bag: Path, *, ros2_decoder: bool) -> dict[str, np.ndarray]:
    from mcap.reader import make_reader

    files = sorted(bag.glob("*.mcap")) if bag.is_dir() else [bag]
    rows: dict[str, list] = {r: [] for r in ROLES}
    for f in files:
        with f.open("rb") as stream:
            if ros2_decoder:
                from mcap_ros2.decoder import DecoderFactory

                reader = make_reader(stream, decoder_factories=[DecoderFactory()])
                for _, channel, _, msg in reader.iter_decoded_messages():
                    if _role(channel.topic):
                        rows[_role(channel.topic)].append(_from_msg(msg))
                continue
            from rosbags.typesys import Stores, get_typestore

            ts = get_typestore(Stores.ROS2_JAZZY)
            reader = make_reader(stream)
            for schema, channel, message in reader.iter_messages(log_time_order=True):
                if _role(channel.topic):
                    msg = ts.deserialize_cdr(message.data, schema.name)
                    rows[_role(channel.topic)].append(_from_msg(msg))
    return _columns(rows)


def _read(way: str, bag: Path) -> dict[str, np.ndarray]:
    if way == "ours":
        return read_ours(bag)
    if way.startswith("rosbags"):
        return read_rosbags(bag, our_cdr=way == "rosbags + our CDR")
    return read_mcap(bag, ros2_decoder=way == "mcap + mcap_ros2")


def _child(way: str, bag: Path, out: Path) -> None:
    t0 = time.process_time()
    cols = _read(way, bag)
    first = time.process_time() - t0
    t1 = time.process_time()
    _read(way, bag)
    second = time.process_time() - t1
    np.savez(out, **cols)
    print(json.dumps({"first_s": first, "second_s": second}))


def _recovery(bag: Path, repeat: int) -> None:
    """scan_mcap against mcap's StreamReader on the bag's MCAP cut at 40 %."""
    import tempfile

    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    from pmdc_ident.dataio.mcap_recover import scan_mcap

    src = next(iter(sorted(bag.glob("*.mcap")))) if bag.is_dir() else bag
    data = src.read_bytes()
    with tempfile.TemporaryDirectory() as tmp:
        cut = Path(tmp) / "cut.mcap"
        cut.write_bytes(data[: int(0.4 * len(data))])

        def library() -> int:
            topics, n = {}, 0
            with cut.open("rb") as f:
                try:
                    for rec in StreamReader(f).records:
                        if isinstance(rec, Channel):
                            topics[rec.id] = rec.topic
                        elif isinstance(rec, Message) and rec.channel_id in topics:
                            n += 1
                except Exception:  # noqa: BLE001 - whatever it raises where the file is cut
                    pass
            return n

        ways = {
            "ours (scan_mcap)": lambda: len(scan_mcap(cut).messages),
            "mcap StreamReader": library,
        }
        best, got = {}, {}
        for name, fn in ways.items():
            for _ in range(repeat):
                t0 = time.process_time()
                got[name] = fn()
                best[name] = min(best.get(name, np.inf), time.process_time() - t0)
    print(f"cut at 40 % ({int(0.4 * len(data)) / 1e6:.1f} MB): CPU s, best of {repeat}")
    t0 = best["ours (scan_mcap)"]
    for name in ways:
        print(f"{name:<20} {best[name]:12.3f} {best[name] / t0:7.1f}   {got[name]} messages")


def _newest_demo_bag() -> Path | None:
    bags = sorted(REPO.glob("pmdc_sessions/demo/*/metadata.yaml"), key=lambda p: p.stat().st_mtime)
    return bags[-1].parent if bags else None


def _same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    """Stamps and every value both ways give (NaN where a way does not read the field)."""
    for r in ROLES:
        if a[r].shape[0] != b[r].shape[0]:
            return False
        for k in range(4):
            x, y = a[r][:, k], b[r][:, k]
            both = np.isfinite(x) & np.isfinite(y)
            if both.any() and not np.array_equal(x[both], y[both]):
                return False
        if not np.array_equal(a[r][:, 0], b[r][:, 0]):
            return False
    return True


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bag", type=Path, help="a session bag (default: newest make demo bag)")
    ap.add_argument("--repeat", type=int, default=3, help="fresh processes per way (best)")
    ap.add_argument("--recovery-only", action="store_true", help="only the cut-bag table")
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        _child(args.child, args.bag, args.out)
        return 0
    bag = args.bag or _newest_demo_bag()
    if bag is None:
        print("no session bag: run `make demo` first, or pass --bag BAG", file=sys.stderr)
        return 2
    import tempfile

    if args.recovery_only:
        _recovery(bag, args.repeat)
        return 0
    size = sum(f.stat().st_size for f in (bag.glob("*.mcap") if bag.is_dir() else [bag]))
    print(f"bag {bag} ({size / 1e6:.1f} MB of MCAP)")
    times: dict[str, tuple[float, float]] = {}
    results: dict[str, dict[str, np.ndarray]] = {}
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    with tempfile.TemporaryDirectory() as tmp:
        for way in WAYS:
            best = (np.inf, np.inf)
            for k in range(args.repeat):
                out = Path(tmp) / f"{WAYS.index(way)}_{k}.npz"
                cmd = [sys.executable, __file__, "--child", way, "--bag", str(bag)]
                p = subprocess.run(
                    [*cmd, "--out", str(out)], capture_output=True, text=True, env=env, check=False
                )
                if p.returncode:
                    print(f"{way}: failed\n{p.stderr.strip()[-2000:]}", file=sys.stderr)
                    return 1
                t = json.loads(p.stdout.strip().splitlines()[-1])
                best = (min(best[0], t["first_s"]), min(best[1], t["second_s"]))
            times[way] = best
            with np.load(out) as z:
                results[way] = {r: z[r] for r in ROLES}
    n = sum(results["ours"][r].shape[0] for r in ROLES)
    print(f"{n} driver messages; CPU s, best of {args.repeat} fresh processes per way")
    print(f"{'way':<20} {'first read':>12} {'x ours':>7} {'second read':>14} {'x ours':>7}")
    f0, s0 = times["ours"]
    for way in WAYS:
        f, s = times[way]
        print(f"{way:<20} {f:12.3f} {f / f0:7.1f} {s:14.3f} {s / s0:7.1f}")
    bad = [w for w in WAYS if not _same(results["ours"], results[w])]
    if bad:
        print(f"DIFFERENT samples from: {', '.join(bad)}", file=sys.stderr)
        return 1
    print("every way read the same stamps and values")
    _recovery(bag, args.repeat)
    return 0


if __name__ == "__main__":
    sys.exit(main())
