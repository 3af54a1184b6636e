"""``bringup``: driver, recorder and identification as separate processes, without ``ros2 launch``.

Starts the three nodes with the DDS environment kept on this machine (the
loopback Fast DDS profile, ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, one
``ROS_DOMAIN_ID``), runs one identification session (``exit_when_done``), then
stops the recorder (the bag is closed) and the driver (the motor is made safe).
Ctrl-C or SIGTERM is forwarded in the safe order: identification first (it
aborts the session and makes the motor safe), then the recorder, then the
driver. Prints the bag and the identified parameters.

For a real ROS install, ``launch/session.launch.py`` starts the same graph.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import yaml

from pmdc_ident.core.enums import ExitCode
from pmdc_ident.core.motors import share_file
from pmdc_ident.core.workers import pdeathsig_preexec
from pmdc_ident.process.dds_domain import HELD_ENV, DomainBusyError, child_env, lock_domain
from pmdc_ident.process.parameter_tables import DRIVER, IDENTIFICATION, RECORDER
from pmdc_ident.process.priority import RT_PRIORITY, priority_setter, realtime_thread

__all__ = [
    "RT_PRIORITY",
    "BringupResult",
    "main",
    "node_env",
    "priority_setter",
    "realtime_thread",
    "run_session",
]


def node_env(
    domain_id: int | None = None, base: Mapping[str, str] | None = None
) -> dict[str, str]:
    """The environment every child node gets: DDS on loopback, one domain."""
    env = dict(os.environ if base is None else base)
    for k in ("ROS_STATIC_PEERS", "ROS_DISCOVERY_SERVER", "ROS_LOCALHOST_ONLY"):
        env.pop(k, None)
    profile = share_file("config", "fastdds_localhost.xml")
    if profile is not None:
        env["FASTDDS_DEFAULT_PROFILES_FILE"] = str(profile)
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(profile)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(int(domain_id))
    env.setdefault("ROS_DOMAIN_ID", "42")
    env.pop(HELD_ENV, None)
    env.update(child_env(int(env["ROS_DOMAIN_ID"])))  # the domain lock we hold, for them
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _ros_args(params_file: Path | None, params: Mapping[str, Any]) -> list[str]:
    args = ["--ros-args"]
    if params_file is not None:
        args += ["--params-file", str(params_file)]
    for name, value in params.items():
        text = yaml.safe_dump(value, default_flow_style=True).strip()
        text = text.removesuffix("\n...").removesuffix("...").strip()
        args += ["-p", f"{name}:={text}"]
    return args


@dataclass
class BringupResult:
    """What a session left: exit codes, the bag, the result JSON (None if none).

    ``bag`` is this session's own bag (a folder created during it), never an older one
    in the same output folder; ``bag_complete`` says whether its recorder closed it
    (``metadata.yaml`` written). ``result`` is the ``parameters.json`` written beside
    it during this session, else None."""

    identification_rc: int | None
    recorder_rc: int | None
    driver_rc: int | None
    bag: Path | None
    result: dict[str, Any] | None
    status: dict[str, Any] | None
    wall_s: float
    logs: dict[str, Path] = field(default_factory=dict)
    cpu_s: dict[str, float | None] = field(default_factory=dict)  # per node, user+system
    bag_complete: bool = False

    @property
    def ok(self) -> bool:
        """The session ran to its end and was identified."""
        return self.identification_rc == 0 and self.result is not None


class _Proc:
    def __init__(
        self,
        name: str,
        module: str,
        ros_args: list[str],
        env: dict[str, str],
        log: IO[str] | None,
        nice: int = 0,
        realtime: bool = False,
        keep_fds: tuple[int, ...] = (),
    ) -> None:
        self.name = name
        cmd = [sys.executable, "-m", module, *ros_args]

        self.popen = subprocess.Popen(
            cmd,
            env=env,
            # SIGTERM (a clean stop: the motor made safe, the bag closed) when this
            # process dies, even by kill -9; then the node's scheduling
            preexec_fn=pdeathsig_preexec(signal.SIGTERM, then=priority_setter(nice, realtime)),
            stdout=log if log is not None else None,
            stderr=subprocess.STDOUT if log is not None else None,
            start_new_session=True,  # our Ctrl-C is forwarded, not delivered twice
            pass_fds=keep_fds,  # the domain lock: held until the last node is gone
        )

        self.cpu_s: float | None = None  # user + system CPU time of the process
        self.interrupted = False  # SIGINT sent

    def poll(self) -> int | None:
        """Exit status once the process ended (reaped with its CPU time), else None."""
        p = self.popen
        if p.returncode is not None:
            return p.returncode
        try:
            pid, status, ru = os.wait4(p.pid, os.WNOHANG)
        except ChildProcessError:
            return p.poll()
        if pid == 0:
            return None
        p.returncode = os.waitstatus_to_exitcode(status)
        self.cpu_s = ru.ru_utime + ru.ru_stime
        return p.returncode

    def wait(self, timeout_s: float) -> int | None:
        deadline = time.monotonic() + timeout_s
        while self.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        return self.popen.returncode

    def interrupt(self) -> None:
        """Ask the node to stop (one SIGINT) without waiting for it."""
        if self.poll() is None and not self.interrupted:
            self.interrupted = True
            self.popen.send_signal(signal.SIGINT)

    def stop(self, timeout_s: float = 10.0) -> int | None:
        if self.poll() is None:
            self.interrupt()
            if self.wait(timeout_s) is None:
                self.popen.terminate()
                if self.wait(3.0) is None:
                    self.popen.kill()
                    self.wait(5.0)
        return self.popen.returncode


def run_session(
    *,
    output_dir: str | Path = RECORDER["output_dir"].default,
    motor: str = DRIVER["motor"].default,
    domain_id: int | None = None,
    driver_params: Mapping[str, Any] | None = None,
    identification_params: Mapping[str, Any] | None = None,
    recorder_params: Mapping[str, Any] | None = None,
    log_dir: str | Path | None = None,
    timeout_s: float = 900.0,
    quiet: bool = False,
    with_recorder: bool = True,
    nice: int = -5,
    realtime: Sequence[str] = ("driver", "recorder", "identification"),
    during: Callable[[dict[str, subprocess.Popen[bytes]], float], None] | None = None,
    before_identification: Callable[[], None] | None = None,
) -> BringupResult:
    """Start the three nodes, run one session, stop them in the safe order (see
    :func:`_watch`).

    ``before_identification()`` runs once the driver and the recorder are started
    and before the identification node is (a test waits there until its own
    observer receives the driver's samples, so it sees the whole session).

    ``during(processes, elapsed_s)`` is called about every 50 ms while the
    session runs (tests use it to break things on purpose). The nodes named in
    ``realtime`` run SCHED_RR where the system permits it, the others (and all of
    them where it does not) at ``nice`` (see :func:`priority_setter`): a motor loop
    and its recorder must not wait behind a compiler or another test suite.
    """
    t0 = time.monotonic()
    started_wall = time.time()
    out = Path(output_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    before = {p.name for p in out.iterdir()}  # this session's bag is a new folder
    logs, files = _log_files(log_dir, quiet)
    args = {
        "driver": {"motor": motor, **(driver_params or {})},
        "recorder": {"output_dir": str(out), **(recorder_params or {})},
        "identification": {
            "motor": motor,
            "exit_when_done": True,
            "output_dir": str(out),
            "require_recorder": with_recorder,
            **(identification_params or {}),
        },
    }
    # No other session, test or demo on this machine may use our domain while we run.
    try:
        domain = int(node_env(domain_id)["ROS_DOMAIN_ID"])
        lock = lock_domain(domain, purpose=f"bringup session in {out}")
    except DomainBusyError:
        _close(files.values())
        raise
    env = node_env(lock.domain_id)  # now with the lock handed to the children
    fd = lock.fileno()
    keep = (fd,) if fd is not None else ()
    procs: dict[str, _Proc] = {}
    rc: dict[str, int | None] = {}
    try:
        with _forward_signals(procs):
            for name in ("driver", "recorder"):
                if name == "driver" or with_recorder:
                    procs[name] = _start(name, args[name], env, files[name], nice, realtime, keep)
            if before_identification is not None:
                before_identification()
            ident_log = files["identification"]
            procs["identification"] = _start(
                "identification", args["identification"], env, ident_log, nice, realtime, keep
            )
            _watch(
                procs, t0, timeout_s, during, lambda: _bag_closed_since(out, before, started_wall)
            )
            rc["identification"] = procs["identification"].stop(timeout_s=10.0)
    finally:
        for name in ("identification", "recorder", "driver"):
            if name in procs:
                rc[name] = procs[name].stop(timeout_s=10.0)
        lock.release()
        _close(files.values())
    return _result(out, before, started_wall, rc, procs, logs, t0)


def _log_files(
    log_dir: str | Path | None, quiet: bool
) -> tuple[dict[str, Path], dict[str, IO[str] | None]]:
    logs: dict[str, Path] = {}
    files: dict[str, IO[str] | None] = {}
    for name in ("driver", "recorder", "identification"):
        if log_dir is not None:
            Path(log_dir).mkdir(parents=True, exist_ok=True)
            logs[name] = Path(log_dir) / f"{name}.log"
            files[name] = logs[name].open("w")
        else:
            files[name] = subprocess.DEVNULL if quiet else None  # type: ignore[assignment]
    return logs, files


_TABLES = {"driver": DRIVER, "recorder": RECORDER, "identification": IDENTIFICATION}


def _start(
    name: str,
    params: Mapping[str, Any],
    env: dict[str, str],
    log: Any,
    nice: int,
    realtime: Sequence[str],
    keep_fds: tuple[int, ...] = (),
) -> _Proc:
    """``name``'s node as a child, with its parameters file and ``params`` on top."""
    table = _TABLES[name]
    module = f"pmdc_ident.nodes.{table.node}"
    args = _ros_args(share_file("config", table.config), params)
    return _Proc(name, module, args, env, log, nice, realtime=name in realtime, keep_fds=keep_fds)


@contextmanager
def _forward_signals(procs: Mapping[str, _Proc]) -> Iterator[None]:
    """Ctrl-C / SIGTERM / SIGHUP (the terminal closed) go to the identification node
    first (it aborts the session and makes the motor safe); the others are stopped
    after it, in the safe order. A node the identification node never started (a
    signal during start-up) is stopped by the same ``finally``."""

    def forward(_signum: int, _frame: Any) -> None:
        ident = procs.get("identification")
        if ident is not None and ident.popen.returncode is None:
            ident.popen.send_signal(signal.SIGINT)

    if not _in_main_thread():
        yield
        return
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    for s in old:
        signal.signal(s, forward)
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def _watch(
    procs: Mapping[str, _Proc],
    t0: float,
    timeout_s: float,
    during: Callable[[dict[str, subprocess.Popen[bytes]], float], None] | None,
    recorded: Callable[[], bool],
) -> None:
    """Until the identification node exits (a crashed peer is noticed by it).

    Once ``recorded()`` (the recorder closed the session's bag and the result lies
    beside it) the recorder and the driver are stopped together while the
    identification node publishes and exits: nothing of the session is left to record,
    and the motor is at rest. After a failed or interrupted session they are stopped
    after the identification node, the recorder before the driver (it drains first).
    """
    ident = procs["identification"]
    deadline = time.monotonic() + timeout_s
    peers_stopped = False
    while ident.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
        if during is not None:
            during({k: v.popen for k, v in procs.items()}, time.monotonic() - t0)
        if not peers_stopped and recorded():
            peers_stopped = True
            for name in ("recorder", "driver"):
                if name in procs:
                    procs[name].interrupt()


def _result(
    out: Path,
    before: set[str],
    since_s: float,
    rc: Mapping[str, int | None],
    procs: Mapping[str, _Proc],
    logs: dict[str, Path],
    t0: float,
) -> BringupResult:
    bag = _session_bag(out, before)
    result = None
    for doc in ([bag / "parameters.json"] if bag is not None else []) + [out / "parameters.json"]:
        if _written_since(doc, since_s):
            try:
                result = json.loads(doc.read_text())
            except (OSError, ValueError):
                result = None
            break
    return BringupResult(
        identification_rc=rc.get("identification"),
        recorder_rc=rc.get("recorder"),
        driver_rc=rc.get("driver"),
        bag=bag,
        result=result,
        status=None,
        wall_s=time.monotonic() - t0,
        logs=logs,
        cpu_s={name: p.cpu_s for name, p in procs.items()},
        bag_complete=bag is not None and (bag / "metadata.yaml").is_file(),
    )


def _close(files: Any) -> None:
    for f in files:
        if f is not None and hasattr(f, "close"):
            f.close()


def _in_main_thread() -> bool:
    import threading

    return threading.current_thread() is threading.main_thread()


def _written_since(path: Path, since_s: float) -> bool:
    try:
        return path.is_file() and path.stat().st_mtime >= since_s - 1.0
    except OSError:
        return False


def _bag_closed_since(out: Path, before: set[str], since_s: float) -> bool:
    """This session's bag is closed by the recorder (metadata written) and holds a
    result written after ``since_s`` (wall clock): its recording is complete."""
    bag = _session_bag(out, before) if out.is_dir() else None
    if bag is None or not (bag / "parameters.json").is_file():
        return False
    return _written_since(bag / "metadata.yaml", since_s)


def _session_bag(out: Path, before: set[str]) -> Path | None:
    """The bag folder this session's recorder created in ``out`` (one that was not
    there before it started), closed or not; never an older session's bag."""
    try:
        new = [p for p in out.iterdir() if p.is_dir() and p.name not in before]
    except OSError:
        return None
    new = [p for p in new if not p.name.startswith(".") and any(p.glob("*.mcap"))] or [
        p for p in new if not p.name.startswith(".")
    ]
    return max(new, key=lambda p: p.stat().st_mtime) if new else None


def parameter_table(result: Mapping[str, Any]) -> str:
    """The identified parameters as an aligned table (from the identify JSON)."""
    lines = [f"{'parameter':<28} {'value':>12}  {'95 % interval':<28} unit"]
    for name, p in (result.get("parameters") or {}).items():
        ci = p.get("ci95")
        ci_s = f"[{ci[0]:.5g}, {ci[1]:.5g}]" if ci else "-"
        if not p.get("identifiable", True):
            ci_s = "not identifiable"
        lines.append(f"{name:<28} {p['value']:>12.6g}  {ci_s:<28} {p.get('unit', '')}")
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="bringup",
        description="Run one identification session: driver, recorder and identification nodes.",
    )
    parser.add_argument(
        "--motor", default=DRIVER["motor"].default, help="built-in motor or YAML path"
    )
    parser.add_argument("--output-dir", default=RECORDER["output_dir"].default, help="bags")
    parser.add_argument("--domain-id", type=int, default=None, help="ROS_DOMAIN_ID (default: env)")
    parser.add_argument(
        "--backend", default=DRIVER["backend"].default, choices=DRIVER["backend"].choices
    )
    parser.add_argument("--port", default=None, help="serial port (backend serial)")
    parser.add_argument(
        "-p",
        "--param",
        action="append",
        default=[],
        metavar="NODE:NAME=VALUE",
        help="extra parameter, e.g. identification:safe_mode=open (NODE: driver, "
        "identification, recorder)",
    )
    parser.add_argument("--timeout", type=float, default=900.0, help="give up after, s")
    args = parser.parse_args(argv)
    extra: dict[str, dict[str, Any]] = {"driver": {}, "identification": {}, "recorder": {}}
    for item in args.param:
        node, _, rest = item.partition(":")
        name, sep, value = rest.partition("=")
        if node not in extra or not sep or not name:
            print(f"bringup: error: bad --param {item!r} (NODE:NAME=VALUE)", file=sys.stderr)
            return ExitCode.USER_ERROR
        extra[node][name] = yaml.safe_load(value)
    extra["driver"]["backend"] = args.backend
    if args.port:
        extra["driver"]["port"] = args.port
    try:
        res = run_session(
            output_dir=args.output_dir,
            motor=args.motor,
            domain_id=args.domain_id,
            driver_params=extra["driver"],
            identification_params=extra["identification"],
            recorder_params=extra["recorder"],
            timeout_s=args.timeout,
        )
    except DomainBusyError as exc:
        print(f"bringup: error: {exc} (--domain-id)", file=sys.stderr)
        return ExitCode.USER_ERROR
    print(f"bringup: session took {res.wall_s:.1f} s")
    if res.bag is not None:
        closed = "" if res.bag_complete else " (INCOMPLETE: its recorder did not close it)"
        print(f"bringup: bag {res.bag}{closed}")
    if res.ok:
        assert res.result is not None
        print(parameter_table(res.result))
        return 0
    print(
        f"bringup: session {session_outcome(res)}: no parameters of this session "
        f"(identification exit status {res.identification_rc})",
        file=sys.stderr,
    )
    return res.identification_rc or 1


def session_outcome(res: BringupResult) -> str:
    """'aborted', 'interrupted', 'failed' or 'refused', from the identification node's
    exit status (``core.enums.ExitCode``), for the one line that says so."""
    return {
        ExitCode.ABORTED: "ABORTED",
        ExitCode.INTERRUPTED: "interrupted",
        ExitCode.USER_ERROR: "refused",
    }.get(res.identification_rc or -1, "failed")


if __name__ == "__main__":
    sys.exit(main())
