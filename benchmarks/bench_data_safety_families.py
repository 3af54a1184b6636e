"""Rerun issue 28's families; count what broke: data loss, stale results, orphans, tracebacks.

Every case is the user's command as a real process on real files (in a temporary
folder), with real signals; each outcome is judged by an oracle written from the
promise, not from the code:

* DATA-LOSS: an input (recording, sidecar, bag) changed, or a file under a final
  name is partial (a truncated CSV, JSON, YAML or PNG; a bag with fewer samples
  than its source that looks complete);
* STALE: a result that is not this run's whole answer presented as one - exit 0 on
  a bag cut inside its segments, on a glitch or a contradicted unit; an estimate
  outside its own interval; a session report naming an older session's bag;
* ORPHAN: a child process (worker, node) still running 5 s after its parent ended;
* TRACEBACK: "Traceback" or "Fatal Python error" in any output.

Families (as issue 28 lists them): batch/report/sidecar outputs over inputs, a full
disk, Ctrl-C during export and during a batch re-run; cut bags, a topic at half rate,
``1_000`` cells, a 1000 A glitch, contradicted and impossible speed units; SIGTERM /
SIGHUP / SIGKILL of a batch and of the benchmark; Ctrl-C in the first 40 ms. With
``--ros`` also the session families (the recorder killed under ``bringup``, ``kill -9``
and SIGHUP of ``bringup``), about two minutes more.

Run: ``nice .venv/bin/python benchmarks/bench_data_safety_families.py [--ros]``; it prints
one line per case and the counts. Not a test (minutes, real processes, a tmpfs where
the process may mount one).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import psutil

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "test"))
# PMDC_FAMILIES_EXE: another pmdc-ident (e.g. an older checkout's wrapper, to count its failures)
EXE = os.environ.get("PMDC_FAMILIES_EXE") or str(Path(sys.executable).parent / "pmdc-ident")
PY = [sys.executable, "-c", "import sys; from pmdc_ident.cli import main; sys.exit(main())"]
FAMILIES = ("data-loss", "stale", "orphans", "tracebacks")


@dataclass
class Tally:
    cases: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FAMILIES, 0))
    broken: dict[str, int] = field(default_factory=lambda: dict.fromkeys(FAMILIES, 0))

    def record(self, family: str, name: str, ok: bool, detail: str = "") -> None:
        self.cases[family] += 1
        self.broken[family] += not ok
        mark = "ok  " if ok else "FAIL"
        print(
            f"  {mark} [{family}] {name}{': ' + detail if detail and not ok else ''}", flush=True
        )

    def output(self, name: str, *texts: str) -> None:
        bad = any("Traceback" in t or "Fatal Python error" in t for t in texts)
        self.record("tracebacks", name, not bad, next((t[-300:] for t in texts if t), ""))


def run(argv: list[str], cwd: Path, timeout: float = 600.0) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    env.pop("PMDC_IDENT_DEBUG", None)
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=timeout, env=env)


def digest(*paths: Path) -> str:
    h = hashlib.sha256()
    for p in paths:
        files = [p] if p.is_file() else sorted(f for f in p.rglob("*") if f.is_file())
        for f in files:
            h.update(str(f).encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def _session_run(seconds: float = 1.0):  # noqa: ANN202
    from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
    from pmdc_ident.core.motors import load_motor

    spec = load_motor("seed000_ebike")
    cfg = SequenceConfig(
        staircase_levels=3, staircase_hold_tau=3.0, step_hold_tau=3.0, sweep_duration_tau=10.0
    )
    return synthesize_run(spec.model, plan_for_motor(spec, 1e-3, cfg), spec.sensors, seed=1)


# ---------------------------------------------------------------------------------------
def outputs_over_inputs(t: Tally, d: Path) -> None:
    from pmdc_ident.dataio.csvio import write_csv

    print("outputs over inputs (batch, report, sidecar)")
    table = REPO / "test" / "fixtures" / "seed000_table4.csv"
    logs = d / "logs"
    logs.mkdir()
    shutil.copy(table, logs / "run.txt")
    write_csv(_session_run(), logs / "session.csv")
    (logs / "session.csv.yaml").write_text("current_unit: A\n")
    x = d / "X"
    x.mkdir()
    shutil.copy(logs / "session.csv", x / "drift.csv")  # a session the monitor replays
    cases = [
        ("identify --batch logs logs", [EXE, "identify", "--batch", "logs", "logs"]),
        ("identify --batch logs 'logs/*'", [EXE, "identify", "--batch", "logs", "logs/*"]),
        ("diagnose --batch logs logs", [EXE, "diagnose", "--batch", "logs", "logs"]),
        (
            "monitor X/drift.csv --report X",
            [EXE, "monitor", "X/drift.csv", "--params", "seed000_ebike", "--report", "X"],
        ),
        (
            "identify run --yaml run.yaml (its sidecar)",
            [EXE, "identify", "logs/session.csv", "--yaml", "logs/session.csv.yaml", "--quiet"],
        ),
    ]
    for name, argv in cases:
        before = digest(logs, x)
        r = run(argv, d)
        t.record("data-loss", name, digest(logs, x) == before, r.stderr[-200:])
        t.output(name, r.stdout, r.stderr)


def full_disk(t: Tally, d: Path) -> None:
    from helpers.full_disk import files_in, nearly_full

    from pmdc_ident.dataio.csvio import write_csv

    print("a full disk")
    src = write_csv(_session_run(), d / "run.csv")
    previous = b"the previous, complete result\n"
    for name, argv, keep in (
        ("export --csv", ["export", str(src), "--csv", "{o}/out.csv"], "out.csv"),
        ("identify --json", ["identify", str(src), "--quiet", "--json", "{o}/r.json"], "r.json"),
        ("identify --yaml", ["identify", str(src), "--quiet", "--yaml", "{o}/m.yaml"], "m.yaml"),
        ("identify --report (PNG)", ["identify", str(src), "--quiet", "--report", "{o}/rep"], ""),
        ("export --bag", ["export", str(src), "--bag", "{o}/bag"], ""),
    ):
        out = d / f"disk_{name.split()[1].strip('-')}_{len(name)}"
        with nearly_full(out, leave_bytes=0, keep={keep: previous} if keep else {}) as mode:
            before = files_in(out)
            r = run([*PY, *(a.format(o=out) for a in argv)], d)
            after = files_in(out)
        ok = after == before and r.returncode == 2
        t.record("data-loss", f"{name} on a full disk ({mode})", ok, r.stderr[-200:])
        t.output(name, r.stderr)


def ctrl_c_during_export(t: Tally, d: Path) -> None:
    from pmdc_ident.dataio.bagio import read_bag, write_bag
    from pmdc_ident.dataio.csvio import read_csv, write_csv

    print("Ctrl-C during export --bag / --csv")
    run_ = _session_run()
    src = write_csv(run_, d / "src.csv")
    bag = write_bag(run_, d / "srcbag")
    n = sum(s.n for s in run_.segments)
    for k, delay in enumerate(np.linspace(0.3, 4.0, 8)):
        for kind, argv, target in (
            ("--bag", [*PY, "export", str(src), "--bag", f"out{k}"], d / f"out{k}"),
            ("--csv", [*PY, "export", str(bag), "--csv", f"out{k}.csv"], d / f"out{k}.csv"),
        ):
            if kind == "--csv":
                target.write_text("t,voltage\n0,1\n")  # an existing file it may replace
            proc = subprocess.Popen(
                argv, cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
            )
            time.sleep(delay)
            proc.send_signal(signal.SIGINT)
            _, err = proc.communicate(timeout=300)
            ok = True
            if target.is_dir():
                ok = (target / "metadata.yaml").is_file() and sum(
                    s.n for s in read_bag(target).segments
                ) == n
            elif target.is_file() and target.read_text() != "t,voltage\n0,1\n":
                ok = sum(s.n for s in read_csv(target).segments) == n
            leftovers = [p.name for p in d.iterdir() if ".partial" in p.name]
            ok = ok and not leftovers
            t.record("data-loss", f"export {kind}, Ctrl-C at {delay:.2f} s", ok, err[-200:])
            t.output(f"export {kind}", err)


def batch_rerun(t: Tally, d: Path) -> None:
    from pmdc_ident.dataio.csvio import write_csv

    print("an interrupted --batch re-run")
    data = d / "bin"
    data.mkdir()
    for k in range(4):
        write_csv(_session_run(), data / f"r{k}.csv")
    out = d / "bout"
    r = run([EXE, "identify", "--batch", str(out), "--jobs", "2", str(data), "--no-holdout"], d)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    for delay in (0.5, 2.0, 4.0):
        argv = [EXE, "identify", "--batch", str(out), "--jobs", "2", str(data), "--no-holdout"]
        proc = subprocess.Popen(
            argv, cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
        )
        time.sleep(delay)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=300)
        after = {p.name: p.read_bytes() for p in out.iterdir()}
        whole = all(v and (not k.endswith(".json") or json.loads(v)) for k, v in after.items())
        ok = whole and set(after) == set(before) and not [k for k in after if "partial" in k]
        t.record("data-loss", f"batch re-run, Ctrl-C at {delay} s", ok, err[-200:])
        t.output("batch re-run", err)
    t.output("batch first run", r.stderr)


# ---------------------------------------------------------------------------------------
def stale(t: Tally, d: Path) -> None:
    from helpers.motor_records import Motor, prbs, simulate, steps, write_csv
    from rosbags.rosbag2 import Reader

    from pmdc_ident.dataio.bagio import TOPIC_TYPES, BagWriter, write_bag
    from pmdc_ident.dataio.mcap_recover import scan_mcap

    print("stale or partial results presented as whole")
    run_ = _session_run()
    bag = write_bag(run_, d / "bag", flush_s=0.002)
    rec = scan_mcap(next(bag.glob("*.mcap")))
    first = run_.segments[0].n
    cuts = [e for e, m in rec.chunk_ends if 30 < m < 3 * (first - 10)]
    for k, end in enumerate(cuts[:3]):
        cut = d / f"cut{k}"
        cut.mkdir()
        (cut / "c.mcap").write_bytes(next(bag.glob("*.mcap")).read_bytes()[: end + 7])
        for cmd in ("identify", "diagnose", "check", "export"):
            argv = [EXE, cmd, str(cut)] + (
                ["--csv", str(d / f"e{k}.csv")] if cmd == "export" else []
            )
            r = run(argv, d)
            t.record(
                "stale",
                f"{cmd} on a bag cut in its first segment ({end} B)",
                r.returncode != 0,
                r.stdout[-200:],
            )
            t.output(cmd, r.stderr)
    # a topic at half the rate
    topics = {k: v for k, v in TOPIC_TYPES.items() if k != "voltage_cmd"}
    with Reader(bag) as rd, BagWriter(d / "half", topics) as w:
        count = 0
        for c, ts, raw in rd.messages():
            if c.topic == "current":
                count += 1
                if count % 2 == 0:
                    continue
            w.write_raw(c.topic, ts, raw)
    r = run([EXE, "identify", str(d / "half"), "--quiet", "--json", str(d / "half.json")], d)
    ok = r.returncode == 0
    if ok:
        from pmdc_ident.core.motors import load_motor

        p = load_motor("seed000_ebike").model.params
        doc = json.loads((d / "half.json").read_text())["parameters"]
        for name, v in {"R": p.R, "Ke": p.Ke, "J": p.J * p.Ke / p.Kt}.items():
            lo, hi = doc[name]["ci95"]
            ok = ok and lo <= v <= hi
    t.record("stale", "a bag with /current at half the rate: estimates inside their intervals", ok)
    t.output("half rate", r.stderr)
    # cells and units
    rec2 = simulate(
        Motor(),
        np.concatenate([steps([6.0, 12.0, -8.0, 0.0, 10.0], 0.3, 1000.0), prbs(500, 8.0, 3)]),
        1000.0,
        noise_current=0.002,
        noise_speed=0.05,
        seed=3,
    )
    clean = write_csv(d / "clean.csv", rec2)
    lines = clean.read_text().splitlines()
    cells = lines[1234].split(",")
    cells[2] = "1_000"
    lines[1234] = ",".join(cells)
    (d / "underscore.csv").write_text("\n".join(lines) + "\n")
    rec3 = simulate(
        Motor(),
        np.concatenate([steps([6.0, 12.0, -8.0, 0.0, 10.0], 0.3, 1000.0), prbs(500, 8.0, 3)]),
        1000.0,
        noise_current=0.002,
        noise_speed=0.05,
        seed=3,
    )
    rec3.current[1234] = 1000.0
    write_csv(d / "glitch.csv", rec3)
    write_csv(d / "degs.csv", rec2, scale={"speed": 180 / math.pi}, drop=("position",))
    for name, argv in (
        ("a 1_000 cell", [EXE, "identify", "underscore.csv", "--quiet"]),
        ("one 1000 A glitch", [EXE, "identify", "glitch.csv", "--quiet"]),
        (
            "--speed-unit rpm that the position contradicts",
            [EXE, "identify", "clean.csv", "--quiet", "--speed-unit", "rpm"],
        ),
        ("deg/s speed without a position column", [EXE, "identify", "degs.csv", "--quiet"]),
    ):
        r = run(argv, d)
        t.record("stale", name + ": refused, never exit 0", r.returncode == 2, r.stdout[-200:])
        t.output(name, r.stderr)


# ---------------------------------------------------------------------------------------
def _descendants(pid: int) -> list[psutil.Process]:
    try:
        return psutil.Process(pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []


def _alive(procs: list[psutil.Process], wait_s: float) -> list[psutil.Process]:
    _, alive = psutil.wait_procs(procs, timeout=wait_s)
    return [p for p in alive if p.status() != psutil.STATUS_ZOMBIE]


def _finish(proc: subprocess.Popen[str], timeout: float = 120.0) -> str:
    """The process's stderr once it ended; an orphan that kept the pipe open (an older
    pmdc-ident's worker) must not hang the count: its parent's end is enough."""
    try:
        return proc.communicate(timeout=timeout)[1] or ""
    except subprocess.TimeoutExpired:
        proc.wait(timeout=timeout)
        return ""


def _reap(procs: list[psutil.Process]) -> None:
    """Stop what this script started and left running (an orphan it just counted)."""
    for p in procs:
        try:
            p.kill()
        except psutil.Error:
            pass
    psutil.wait_procs(procs, timeout=5.0)


def orphans(t: Tally, d: Path) -> None:
    from pmdc_ident.dataio.csvio import write_csv

    print("processes that outlive their parent")
    data = d / "oin"
    data.mkdir()
    for k in range(4):
        write_csv(_session_run(), data / f"r{k}.csv")
    cmds = {
        "identify --batch": [
            EXE,
            "identify",
            "--batch",
            str(d / "oout"),
            "--jobs",
            "2",
            str(data),
        ],
        "benchmark --jobs 2": [EXE, "benchmark", "--quick", "--jobs", "2", "--quiet"],
    }
    for name, argv in cmds.items():
        for sig in (signal.SIGTERM, signal.SIGHUP, signal.SIGKILL, signal.SIGINT):
            proc = subprocess.Popen(
                argv, cwd=d, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True
            )
            deadline = time.monotonic() + 60
            kids: list[psutil.Process] = []
            while time.monotonic() < deadline and len(kids) < 2 and proc.poll() is None:
                time.sleep(0.2)
                kids = _descendants(proc.pid)
            time.sleep(1.0)
            kids = _descendants(proc.pid) or kids
            proc.send_signal(sig)
            err = _finish(proc)
            alive = _alive(kids, 5.0)
            t.record(
                "orphans",
                f"{signal.Signals(sig).name} to {name} ({len(kids)} children)",
                not alive and len(kids) >= 2,
                str([p.pid for p in alive]),
            )
            t.output(name, err)
            _reap(alive + _descendants(proc.pid))
            if "leaked semaphore" in err or "resource_tracker" in err:
                t.record("tracebacks", f"{name}: resource tracker warning", False, err[-200:])


def early_ctrl_c(t: Tally, d: Path, trials: int = 40) -> None:
    print(f"Ctrl-C within the first {trials} ms of a command")
    bad = 0
    for k in range(trials):
        proc = subprocess.Popen(
            [EXE, "check", "/nonexistent.csv"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        time.sleep(k * 0.001)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
        ok = "Traceback" not in err and "Fatal Python error" not in err
        t.cases["tracebacks"] += 1
        t.broken["tracebacks"] += not ok
        bad += not ok
    mark = "ok  " if not bad else "FAIL"
    print(f"  {mark} [tracebacks] {trials} Ctrl-C at 0..{trials - 1} ms: {bad} traceback(s)")


# ---------------------------------------------------------------------------------------
def ros_sessions(t: Tally, d: Path) -> None:
    from pmdc_ident.process.bringup import node_env
    from pmdc_ident.process.dds_domain import allocate_domain

    print("identification sessions (bringup)")
    base = [
        "-p",
        "identification:sequence.staircase_levels=3",
        "-p",
        "identification:sequence.staircase_hold_tau=5.0",
        "-p",
        "identification:sequence.sweep_duration_tau=20.0",
        "-p",
        "identification:safety.data_timeout_s=1.5",
        "-p",
        "driver:watchdog_s=1.5",
    ]
    with allocate_domain(purpose="bench_data_safety_families") as lock:
        for case in ("recorder killed", "SIGKILL of bringup", "SIGHUP of bringup"):
            out = d / case.replace(" ", "_")
            old = out / "older_session"
            old.mkdir(parents=True)
            (old / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
            (old / "parameters.json").write_text('{"parameters": {"R": {"value": 99.0}}}')
            env = node_env(lock.domain_id)
            env.pop("PMDC_DDS_DOMAIN_HELD", None)
            env["PMDC_DDS_LOCK_DIR"] = str(d)
            argv = [
                sys.executable,
                "-m",
                "pmdc_ident.process.bringup",
                "--motor",
                "seed001_110v",
                "--output-dir",
                str(out),
                "--domain-id",
                str(lock.domain_id),
                *base,
            ]
            proc = subprocess.Popen(
                argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
            )
            lines = []
            assert proc.stdout is not None
            for line in proc.stdout:
                lines.append(line)
                if "segments, nominal" in line:
                    break
            time.sleep(2.0)
            nodes = _descendants(proc.pid)
            if case == "recorder killed":
                for p in nodes:
                    if "recorder_node" in " ".join(p.cmdline()):
                        p.kill()
            else:
                proc.send_signal(signal.SIGKILL if "KILL" in case else signal.SIGHUP)
            rest, _ = proc.communicate(timeout=180)
            text = "".join(lines) + (rest or "")
            alive = _alive(nodes, 20.0)
            t.record("orphans", f"{case}: every node ends", not alive, str(alive))
            _reap(alive)
            if case != "SIGKILL of bringup":
                stale_ok = (
                    proc.returncode != 0
                    and "older_session" not in text
                    and "99" not in text.split("session took")[-1]
                )
                t.record(
                    "stale",
                    f"{case}: reports this session (never the older one), exit != 0",
                    stale_ok,
                    text[-300:],
                )
            t.output(case, text)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ros", action="store_true", help="also the bringup session families")
    ap.add_argument("--only", metavar="NAME", help="only this family function (e.g. stale)")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()}", flush=True)
    t = Tally()
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="pmdc_families_") as tmp:
        d = Path(tmp)
        families = (
            outputs_over_inputs,
            full_disk,
            ctrl_c_during_export,
            batch_rerun,
            stale,
            orphans,
            early_ctrl_c,
        )
        for family in families:
            if args.only and family.__name__ != args.only:
                continue
            sub = d / family.__name__
            sub.mkdir()
            family(t, sub)
        if args.ros and args.only in (None, "ros_sessions"):
            sub = d / "ros"
            sub.mkdir()
            ros_sessions(t, sub)
    print(f"\n{sum(t.cases.values())} checks in {time.monotonic() - t0:.0f} s")
    for fam in FAMILIES:
        print(f"{fam:>11}: {t.broken[fam]} of {t.cases[fam]} checks broken")


if __name__ == "__main__":
    main()
