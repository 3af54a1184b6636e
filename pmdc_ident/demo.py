"""``make demo``: the whole identification session on the built-in simulated motor.

Starts the driver (simulated seed-000 e-bike motor), the recorder and the
identification node as separate processes over DDS on loopback
(:func:`pmdc_ident.process.bringup.run_session`), runs the default sequence
(staircase to steady state, steps both ways, log chirp, coast-down with the
armature open), then prints the identified parameters with their intervals, the
bag's path, and the sim-to-real gap diagnosis of that bag.

ROS is imported only in the child processes and the node layer; this module
stays importable without ROS.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

from pmdc_ident.core.enums import ExitCode
from pmdc_ident.core.errors import PmdcError

__all__ = ["main", "run_session_demo"]


def _follow(log: Path) -> Any:
    """A ``during`` callback printing the identification node's new log lines."""
    state = {"pos": 0}

    def during(_procs: Any, _elapsed: float) -> None:
        if not log.is_file():
            return
        with log.open() as fh:
            fh.seek(state["pos"])
            text = fh.read()
            state["pos"] = fh.tell()
        for line in text.splitlines():
            if "] [identification_node]: " in line:
                print("  " + line.split("] [identification_node]: ", 1)[1], flush=True)
            elif line.startswith(("  ", "model:", "parameter")):
                continue  # the result table is printed once below

    return during


def run_session_demo(
    *, output_dir: str | Path = "pmdc_sessions/demo", motor: str = "seed000_ebike"
) -> int:
    out = Path(output_dir)
    logs = out / "logs"
    with _own_domain(int(os.environ.get("ROS_DOMAIN_ID", "42"))) as lock:
        return _session_demo(out, logs, motor, lock.domain_id)


def _own_domain(domain: int) -> Any:
    """Lock ``domain`` for this demo, or a free one if another session holds it (said so)."""
    from pmdc_ident.process.dds_domain import DomainBusyError, allocate_domain, lock_domain

    try:
        return lock_domain(domain, purpose="make demo")
    except DomainBusyError as exc:
        lock = allocate_domain(purpose="make demo")
        print(f"demo: {exc}; this demo uses ROS_DOMAIN_ID {lock.domain_id}")
        return lock


def _session_demo(out: Path, logs: Path, motor: str, domain: int) -> int:
    from pmdc_ident.process.bringup import parameter_table, run_session, session_outcome

    print(f"== identification session on the simulated {motor} motor (ROS_DOMAIN_ID {domain})")
    print(f"   driver, recorder and identification nodes in separate processes; logs in {logs}")
    t0 = time.monotonic()
    res = run_session(
        output_dir=out,
        motor=motor,
        domain_id=domain,
        log_dir=logs,
        # A shared 2-core machine stalls processes now and then: tolerate 1.5 s (a bench
        # with a real motor keeps the 0.5 s defaults of config/*.yaml).
        identification_params={"safety.data_timeout_s": 1.5},
        driver_params={"watchdog_s": 1.5},
        during=_follow(logs / "identification.log"),
    )
    print(f"== session finished in {time.monotonic() - t0:.1f} s (wall)")
    if res.bag is not None:
        closed = "" if res.bag_complete else " (INCOMPLETE: its recorder did not close it)"
        print(f"   bag of this session: {res.bag.resolve()}{closed}")
    if not res.ok:
        # never an older session's bag or parameters in place of this one's
        print(
            f"demo: session {session_outcome(res)}: no parameters of this session "
            f"(identification exit status {res.identification_rc}); see {logs}",
            file=sys.stderr,
        )
        return res.identification_rc or 1
    assert res.result is not None and res.bag is not None
    print("== identified parameters (95 % intervals)")
    print(parameter_table(res.result))
    for a in res.result.get("assumptions", []):
        print(f"   assumption: {a}")
    for w in res.result.get("warnings", []):
        print(f"   warning: {w}")
    print(f"   JSON and YAML beside the bag: {res.bag / 'parameters.json'}, parameters.yaml")
    print(f"   offline, without ROS: pmdc-ident identify {res.bag}")
    _diagnose(res.bag)
    return 0


def _diagnose(bag: Path) -> None:
    from pmdc_ident.core.diagnosis import diagnose
    from pmdc_ident.dataio.bagio import read_bag

    print("== sim-to-real gap diagnosis of the bag (held-out segments)")
    t0 = time.monotonic()
    result = diagnose([read_bag(bag)])
    for line in result.summary_lines():
        print("   " + line)
    print(f"   ({time.monotonic() - t0:.1f} s)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m pmdc_ident.demo", description=__doc__)
    ap.add_argument("--output-dir", default="pmdc_sessions/demo", help="where the bag goes")
    ap.add_argument("--motor", default="seed000_ebike", help="built-in motor or YAML path")
    args = ap.parse_args(argv)
    try:
        return run_session_demo(output_dir=args.output_dir, motor=args.motor)
    except PmdcError as exc:
        _say(f"demo: {exc}")
        return ExitCode.FAILED
    except KeyboardInterrupt:
        _say("demo: interrupted")
        return ExitCode.INTERRUPTED
    except OSError as exc:  # the terminal went away (SIGHUP): nothing left to tell
        _say(f"demo: {exc.strerror or exc}")
        return ExitCode.FAILED


def _say(line: str) -> None:
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


if __name__ == "__main__":
    sys.exit(main())
