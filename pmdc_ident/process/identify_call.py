"""The one identification call shared by the online node and ``pmdc-ident identify`` (ROS-free).

:func:`run_identification_job` is what the node runs once a session is over (in a
worker process, so the node keeps serving its topics meanwhile).

The node identifies its session with :func:`identify_session_run`, which calls the
application service of ``pmdc-ident identify`` (:func:`pmdc_ident.app.identify_inputs`:
the data-quality gate, the segments, the fit, the bias flag, the JSON) with that
command's default options; ``fixed`` is its ``--fix NAME=VALUE`` list. So
``pmdc-ident identify <bag> [--fix ...]`` on a laptop prints the same parameters as the
node published, and the JSON is the same document ``pmdc-ident identify --json`` writes
but for the session's own entries (``driver_samples``, ``exports``,
``experiment_design``) and what the bag file adds (``inputs``' notes, ``recording``;
docs/reference.md).
"""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from pmdc_ident.app.options import CLI_NAMES
from pmdc_ident.core.data import Run
from pmdc_ident.core.enums import ExitCode, LogLevel
from pmdc_ident.core.errors import PmdcError, wording
from pmdc_ident.core.excitation import SequenceConfig
from pmdc_ident.core.motors import MotorSpec
from pmdc_ident.core.safe_write import write_text
from pmdc_ident.core.samples import DriverSamples
from pmdc_ident.dataio.bagio import assemble_run
from pmdc_ident.dataio.completeness import Completeness, completeness
from pmdc_ident.node_logic.session.ports import (
    ExportRequest,
    IdentificationJob,
    IdentificationOutcome,
)
from pmdc_ident.node_logic.session.sequential import DesignJob, DesignOutcome

__all__ = [
    "NODE_NAMES",
    "IdentificationWorker",
    "IdentifyOutput",
    "identify_session_run",
    "run_identification_job",
    "warm_up",
    "write_session_exports",
]

EXPORT_STEM = "identified"  # the exports beside the bag: identified.mjcf.xml, ...
WORKER_NICE = -5  # the worker's priority where permitted (see _normal_priority)
WARM_UP_NICE = 10  # while it warms up during the session, where it can raise it again


@dataclass(frozen=True)
class IdentifyOutput:
    json_text: str  # the document of ``pmdc-ident identify --json``
    yaml_text: str  # the motor file of ``pmdc-ident identify --yaml``
    table: str  # the text report the command prints
    values: dict[str, float]
    spec: MotorSpec  # the identified motor (what the YAML holds)

    def with_entry(self, key: str, value: Any) -> IdentifyOutput:
        """The same output with ``key`` added to the JSON document."""
        doc = {**json.loads(self.json_text), key: value}
        return replace(self, json_text=json.dumps(doc, indent=2, allow_nan=False) + "\n")


# the node's words for the core's options (pmdc_ident.core.errors.wording): ``fix`` is its
# ROS parameter; the others it does not have, so a hint names the command that
# re-identifies the bag with them
NODE_NAMES: dict[str, str] = {
    "data": "DATA",
    "fix": "parameter fix",
    **{
        key: f"`pmdc-ident identify BAG {flag}`"
        for key, flag in CLI_NAMES.items()
        if key not in {"data", "fix"}
    },
    # a session runs unattended: a one-sample glitch (an ADC read mid-switch, a stale
    # command applied for one sample under load) is fitted around and reported, not a
    # reason to throw the session away; the command refuses it unless told otherwise
    "drop_outliers": "an unattended session fits around them; `pmdc-ident identify BAG` "
    "refuses them",
    # plan: auto's designs (plan --current-lag-us)
    "current_lag_us": "parameter plan_current_lag_s",
}


def identify_session_run(
    run: Run,
    fixed: Mapping[str, float] | None = None,
    name: str = "identified",
    extra: Mapping[str, Any] | None = None,
    source: str | None = None,
) -> IdentifyOutput:
    """Identify a session's run through the service ``pmdc-ident identify`` calls
    (:func:`pmdc_ident.app.identify_inputs`, that command's default options but
    ``--drop-outliers``: see ``NODE_NAMES``; ``fixed`` is its ``--fix`` list): the same
    gate (outliers, the assumption register, a long record's representative subset), the
    same fit and the same JSON document.

    ``source``: the name of the input in the document (the session's bag path; default
    the run's source). ``extra`` entries are added to the JSON document (the node adds
    how complete its driver samples were).
    """
    from pmdc_ident.app import IdentifyOptions, identify_inputs
    from pmdc_ident.app.inputs import loaded_run
    from pmdc_ident.core.fixed import FixedValues

    path = source or run.source or "session"
    options = IdentifyOptions(
        data=(path,),
        fixed=FixedValues(fixed or {}),
        names=NODE_NAMES,
        motor_name=name,
        drop_outliers=True,
    )
    with wording(NODE_NAMES):
        loaded = loaded_run(options, run, path, origin="the node's driver samples (SI units)")
        docs = identify_inputs(options, loaded=loaded, extra=extra)
    return IdentifyOutput(
        json_text=docs.json_text,
        yaml_text=docs.yaml_text,
        table="\n".join(docs.lines),
        values=docs.values,
        spec=docs.result.motor_spec(name),
    )


def write_session_exports(
    spec: MotorSpec, folder: Path, request: ExportRequest, notes: list[tuple[LogLevel, str]]
) -> dict[str, Any]:
    """The identified motor's MJCF, URDF, ros2_control and gains files in ``folder``
    (:func:`pmdc_ident.exports.write_exports`, stem ``identified``).

    Returns the result document's ``exports`` entry (``files`` written, ``error``);
    never raises: a failure (gains not designable at these settings, a folder not
    writable) is one warning line in ``notes`` and the entry's ``error``.
    """
    from pmdc_ident.exports import write_exports

    try:
        paths = write_exports(
            spec,
            folder,
            stem=EXPORT_STEM,
            reduction=request.reduction,
            joint=request.joint or "motor_joint",
            sample_rate_hz=request.sample_rate_hz,
            speed_bandwidth_hz=request.speed_bandwidth_hz or None,
            phase_margin_deg=request.phase_margin_deg,
        )
    except Exception as exc:  # noqa: BLE001 - the identification stands without them
        why = str(exc) if isinstance(exc, PmdcError | OSError) else repr(exc)
        notes.append((LogLevel.WARNING, f"exports not written: {why}"))
        return {"files": [], "error": why}
    names = [p.name for p in paths]
    notes.append((LogLevel.INFO, f"exports written to {folder}: {', '.join(names)}"))
    return {"files": names, "error": None}


def run_identification_job(job: IdentificationJob) -> IdentificationOutcome:
    """Identify a finished session's samples and write ``parameters.json`` / ``.yaml``
    (and the exports when the job asks for them) beside its bag: what the
    identification node runs once a session is over.

    Runs in a worker process (plain data in and out); never raises: a refusal of the
    data is the outcome's ``error`` with exit code 2, a bug of ours exit code 1. Its
    lines name options in the node's words (:data:`NODE_NAMES`: ``parameter fix``).
    """
    with wording(NODE_NAMES):
        return _identification_job(job)


def _identification_job(job: IdentificationJob) -> IdentificationOutcome:
    notes: list[tuple[LogLevel, str]] = []
    try:
        run = assemble_run(job.samples, source=job.source, session=job.session)
        n = sum(seg.n for seg in run.segments)
        found = _completeness(job.samples)
        notes.append(
            (
                LogLevel.WARNING if found.missing else LogLevel.INFO,
                f"session {job.session}: {found.line()}",
            )
        )
        extra = {"driver_samples": found.to_dict(), **dict(job.extra or {})}
        result = identify_session_run(
            run, job.fixed, name=job.session, extra=extra, source=job.source
        )
        job.output_dir.mkdir(parents=True, exist_ok=True)
        if job.exports is not None:
            made = write_session_exports(result.spec, job.output_dir, job.exports, notes)
            result = result.with_entry("exports", made)
        write_text(job.output_dir / "parameters.json", result.json_text)
        write_text(job.output_dir / "parameters.yaml", result.yaml_text)
    except PmdcError as exc:
        return IdentificationOutcome(
            error=str(exc), exit_code=ExitCode.USER_ERROR, notes=tuple(notes)
        )
    except Exception as exc:  # noqa: BLE001 - report in one line, keep the node alive
        return IdentificationOutcome(
            error=repr(exc), exit_code=ExitCode.FAILED, notes=tuple(notes)
        )
    return IdentificationOutcome(
        json_text=result.json_text,
        table=result.table,
        n_samples=n,
        output_dir=str(job.output_dir),
        notes=tuple(notes),
    )


def run_design_job(job: DesignJob) -> DesignOutcome:
    """A ``plan: auto`` session's re-fit and design (:mod:`pmdc_ident.node_logic.session.
    sequential`) on the samples so far, assembled as the bag would be. Never raises."""
    from pmdc_ident.node_logic.session.sequential import run_design_job as decide

    try:
        run = assemble_run(job.samples, source=job.source, session=job.session)
        with wording(NODE_NAMES):  # a design's advice names the node's parameters
            return decide(job, run)
    except PmdcError as exc:
        return DesignOutcome(
            "stop", design=job.design, message=f"re-fit failed: {exc}", error=str(exc)
        )
    except Exception as exc:  # noqa: BLE001 - one line, the node ends the session safely
        return DesignOutcome(
            "stop", design=job.design, message=f"re-fit failed: {exc!r}", error=repr(exc)
        )


def _completeness(s: DriverSamples) -> Completeness:
    """The session's driver samples the node received vs the stamp grid."""
    enc = np.unique(s.encoder_ns)
    dt_ns = int(np.median(np.diff(enc))) if enc.size > 2 else 1_000_000
    stamps = {"current": s.current_ns, "encoder": s.encoder_ns, "voltage_applied": s.voltage_ns}
    return completeness(
        stamps, round(s.markers[0].t_s * 1e9), round(s.markers[-1].t_s * 1e9), dt_ns
    )


class IdentificationWorker:
    """Identifies finished sessions in a child process, warmed up before it is needed.

    Started when a session starts (:meth:`SessionController` calls the node's
    ``prepare_identification``): while the motor runs, the child imports the
    estimators and identifies a short synthetic run of the nominal motor
    (:func:`warm_up`), so every numba kernel is loaded from the on-disk cache and the
    session's end costs only the fit. It then serves one job at a time over its pipe
    and stays for the next session.

    A process, not a thread: the identification's Python-level work then never holds
    the node's interpreter lock while driver samples and signals must be served, and
    a stop terminates it at once. The child is spawned (never forked: the parent runs
    DDS threads) and gets plain data.
    """

    def __init__(self, nominal: MotorSpec | None = None) -> None:
        ctx = multiprocessing.get_context("spawn")
        self._rt_priority = _job_rt_priority()
        self._conn, child = ctx.Pipe(duplex=True)
        self._process = ctx.Process(
            target=_serve, args=(child, nominal), name="pmdc_ident identification", daemon=True
        )
        # started from the node's executor thread, at its priority: dropping this thread
        # to the normal scheduler for the spawn (a fork of the node) held every driver
        # sample and command for >1.5 s at load 15 (lost_driver_data, driver watchdog).
        # The child is moved to the normal scheduler at once instead (its first
        # milliseconds of interpreter start-up aside); _serve then sets its nice.
        self._process.start()
        if self._process.pid is not None and os.sched_getscheduler(0) != os.SCHED_OTHER:
            _set_policy(self._process.pid, os.SCHED_OTHER, 0)
        child.close()
        self._busy = False
        self._notes: list[tuple[LogLevel, str]] = []

    @property
    def alive(self) -> bool:
        return self._process.is_alive()

    @property
    def busy(self) -> bool:
        """A job was submitted and its outcome not yet returned by :meth:`poll`."""
        return self._busy

    def submit(self, job: IdentificationJob | DesignJob) -> None:
        """Hand a finished session over; :meth:`poll` returns its outcome.

        Sent from a thread: a session's samples are megabytes, more than the pipe
        holds, and a child still warming up reads them only then; the node's callbacks
        must not wait for that."""
        self._busy = True
        if self._process.pid is not None:
            _set_nice(WORKER_NICE, self._process.pid)  # were it still warming up
            # a plan: auto re-fit runs while the motor does: never at real-time priority
            if self._rt_priority and not isinstance(job, DesignJob):
                _set_policy(self._process.pid, os.SCHED_RR, self._rt_priority)
        threading.Thread(
            target=self._send, args=(job,), name="pmdc_ident job", daemon=True
        ).start()

    def _send(self, job: IdentificationJob) -> None:
        try:
            self._conn.send(job)
        except (OSError, ValueError):
            pass  # the child is gone (or we closed): poll() says so

    def poll(self) -> IdentificationOutcome | DesignOutcome | None:
        """The outcome of the submitted job once the child has it (``None`` meanwhile,
        and while no job is submitted)."""
        while self._busy and self._conn.poll():
            try:
                msg = self._conn.recv()
            except (EOFError, OSError):
                break
            if isinstance(msg, DesignOutcome):
                self._busy = False
                if self._rt_priority and self._process.pid is not None:
                    _set_policy(self._process.pid, os.SCHED_OTHER, 0)
                return replace(msg, notes=(*msg.notes, *self._notes))
            if isinstance(msg, IdentificationOutcome):
                self._busy = False
                if self._rt_priority and self._process.pid is not None:
                    _set_policy(self._process.pid, os.SCHED_OTHER, 0)
                notes = (*self._notes, *msg.notes)
                self._notes = []
                return replace(msg, notes=notes)
            self._notes.append(msg)  # the warm-up's line
        if not self._busy or self._process.is_alive():
            return None
        self._busy = False
        code = self._process.exitcode
        return IdentificationOutcome(
            error=f"the identification process ended without a result (exit code {code})",
            exit_code=ExitCode.FAILED,
        )

    def terminate(self) -> None:
        if self._process.is_alive():
            self._process.terminate()
            self._process.join(timeout=5.0)
        self._conn.close()


# A short default sequence (about a tenth of the default's length) for the warm-up.
WARM_UP_SEQUENCE = SequenceConfig(
    staircase_levels=2,
    staircase_hold_tau=3.0,
    step_hold_tau=3.0,
    sweep_duration_tau=6.0,
    coast_spinup_tau=3.0,
    coast_open_s=0.3,
)


def warm_up(nominal: MotorSpec, rate_hz: float = 1000.0) -> float:
    """Identify a short synthetic run of ``nominal`` (discarded): imports the
    estimators and loads every kernel the identification of a session uses. Returns
    the wall time it took, s."""
    from pmdc_ident.core.excitation import plan_for_motor, synthesize_run

    t0 = time.monotonic()
    plan = plan_for_motor(nominal, 1.0 / rate_hz, WARM_UP_SEQUENCE)
    identify_session_run(synthesize_run(nominal.model, plan, source="warm-up"))
    return time.monotonic() - t0


def _serve(conn: Any, nominal: MotorSpec | None) -> None:
    # Ctrl-C reaches the whole process group: the node decides (it terminates this
    # process with SIGTERM when it stops), so no KeyboardInterrupt traceback here.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # and it never outlives the node (killed with -9, its fit would run on for seconds)
    from pmdc_ident.core.workers import die_with_parent

    die_with_parent(signal.SIGKILL)
    fit_nice = _normal_priority()  # the fit is batch work: never at real-time priority
    if nominal is not None:
        cpu0 = time.process_time()
        try:
            # the warm-up has the whole session: it yields to everything else meanwhile
            # (back to the fit's priority only where that is permitted)
            if fit_nice < 0:
                _set_nice(WARM_UP_NICE)
            wall = warm_up(nominal)
            conn.send(
                (
                    LogLevel.INFO,
                    f"identification worker warmed up during the session in {wall:.2f} s "
                    f"({time.process_time() - cpu0:.2f} s CPU)",
                )
            )
        except Exception as exc:  # noqa: BLE001 - the session's own fit still runs
            conn.send(
                (LogLevel.WARNING, f"identification warm-up failed (the fit still runs): {exc!r}")
            )
        finally:
            _set_nice(fit_nice)
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return  # the node is gone
        t0, cpu0 = time.monotonic(), time.process_time()
        if isinstance(job, DesignJob):
            conn.send(run_design_job(job))
            continue
        outcome = run_identification_job(job)
        took = (
            LogLevel.INFO,
            f"session {job.session}: identification took {time.monotonic() - t0:.2f} s "
            f"({time.process_time() - cpu0:.2f} s CPU) in the worker",
        )
        conn.send(replace(outcome, notes=(*outcome.notes, took)))


def _normal_priority() -> int:
    """This process back to the normal scheduler: a child inherits the node's SCHED_RR
    (bring-up runs the session's nodes real-time where permitted). It keeps a raised
    priority where permitted (nice -5, as bring-up's nodes without real-time): the
    fit the session waits for goes before background batch work. Returns the nice
    value it runs at."""
    try:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass
    if os.getpriority(os.PRIO_PROCESS, 0) > WORKER_NICE:
        _set_nice(WORKER_NICE)
    return os.getpriority(os.PRIO_PROCESS, 0)


def _job_rt_priority() -> int:
    """The real-time priority a job runs at: below this node's own (the loop's) when the
    node runs SCHED_RR, else 0 (none). While the session runs the worker is a normal
    process; a finished session's fit then takes the CPU before other (normal) work,
    which on a machine busy with other real-time processes is the difference between
    a second and a minute, and never before the session's nodes."""
    try:
        if os.sched_getscheduler(0) != os.SCHED_RR:
            return 0
        return max(1, os.sched_getparam(0).sched_priority // 2)
    except (OSError, AttributeError):
        return 0


def _thread_ids(pid: int) -> list[int]:
    """The threads of process ``pid`` (itself where /proc cannot be read)."""
    try:
        return [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return [pid]


def _set_policy(pid: int, policy: int, priority: int) -> None:
    """Every thread of process ``pid`` at ``policy``/``priority`` where permitted."""
    for tid in _thread_ids(pid):
        try:
            os.sched_setscheduler(tid, policy, os.sched_param(priority))
        except (OSError, AttributeError):
            pass  # not permitted (or the thread ended): as it was


def _set_nice(value: int, pid: int = 0) -> None:
    """Every thread of process ``pid`` (0: this one) at nice ``value`` where permitted
    (Linux keeps a nice value per thread; the fit's thread pool outlives the warm-up)."""
    for tid in _thread_ids(pid or os.getpid()):
        try:
            os.setpriority(os.PRIO_PROCESS, tid, value)
        except OSError:
            pass  # not permitted (or the thread ended): as it was
