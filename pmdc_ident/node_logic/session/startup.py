"""Starting a session, ROS-free: when the node may start, and the session it starts.

A session starts only when every check passes, in this order (the first unmet one
names what the node waits for, and becomes the refusal when ``driver_wait_s`` runs
out):

1. the driver answered: its limits (voltage, current, speed), motor and rate are read;
2. its samples arrive (one within 0.5 s), on every topic this node records: the
   current and the applied voltage as well as the encoder, each within 0.5 s of the
   encoder's stamp (DDS matches each subscription on its own; on a loaded machine the
   current's could match a quarter of a second after the encoder's, and the first
   samples of the session would be missing from this node's record but not from the
   bag);
3. they arrive on time (latency below ``max_start_latency_s``) and have done so for
   ``settle_s`` (the other processes are done starting up, so the first commands are
   not late);
4. the recorder's heartbeat is fresh (when ``require_recorder``).

The session's abort thresholds default to 90 % of the driver's trip limits, the
stall rule and the lost-data timeout to :meth:`SafetyConfig.for_limits`; the plan is
sized for the nominal motor and checked (:func:`check_plan`) before anything moves.
"""

from __future__ import annotations

import enum
import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from pmdc_ident.core.enums import SafeMode
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.excitation import SequenceConfig, TestPlan, default_plan, plan_for_motor
from pmdc_ident.core.motors import Limits, MotorSpec, load_motor
from pmdc_ident.core.safety import SafetyConfig
from pmdc_ident.node_logic.session.machine import Session
from pmdc_ident.node_logic.session.plan_check import check_plan
from pmdc_ident.node_logic.session.steady_state import SteadyStateConfig

__all__ = [
    "ABORT_FRACTION",
    "DRIVER_PARAMETERS",
    "Peers",
    "SessionSettings",
    "StartCheck",
    "StartRules",
    "build_session",
    "driver_limits",
]

ABORT_FRACTION = 0.9  # default session aborts: this fraction of the driver's trip limits
SAMPLES_STALE_S = 0.5  # no driver sample for this long: the driver is not streaming
RECORDED_TOPICS = ("current", "voltage_applied", "encoder")  # the driver's data topics
# read from the driver node before anything moves
DRIVER_PARAMETERS = (
    "voltage_limit_v",
    "current_limit_a",
    "speed_limit_rad_s",
    "motor",
    "rate_hz",
    "joint_name",  # the exports name the driver's joint
)


class StartCheck(enum.Enum):
    """What a session start waits for (the first unmet check)."""

    DRIVER = "driver"  # no driver parameters yet
    SAMPLES = "samples"  # no recent driver sample
    LATENCY = "latency"  # samples still arrive late
    SETTLE = "settle"  # on time, but not yet for settle_s
    RECORDER = "recorder"  # no fresh recorder heartbeat
    READY = "ready"


@dataclass(frozen=True)
class StartRules:
    """When a session may start (the identification node's parameters)."""

    driver_node: str
    driver_wait_s: float
    max_start_latency_s: float
    settle_s: float
    require_recorder: bool
    peer_timeout_s: float


@dataclass
class Peers:
    """What the identification node knows of the driver and the recorder (times on the
    host's monotonic clock, s)."""

    driver: dict[str, Any] | None = None  # the driver's parameters, once read
    driver_asked: bool = False  # a request for them is on its way
    last_sample_s: float = -math.inf  # the last driver sample arrived
    stamps_ns: dict[str, int] = field(default_factory=dict)  # topic -> its last stamp
    settled_since_s: float = math.inf  # samples on time since
    recorder_seen_s: float = -math.inf  # the recorder's last heartbeat
    recorder_receiving: bool = False  # it has driver samples on every topic
    recorder_paths: dict[str, str] = field(default_factory=dict)  # session -> its bag
    waited_s: dict[str, float] = field(default_factory=dict)  # start-up time per check
    _noted_s: float = math.nan

    def reset(self) -> None:
        """A new session is requested: read the driver's limits again."""
        self.driver = None
        self.driver_asked = False
        self.settled_since_s = math.inf
        self.waited_s = {}
        self._noted_s = math.nan

    def note_wait(self, check: StartCheck, now_s: float) -> None:
        """The start waited for ``check`` since the last note (where start-up time goes)."""
        if not math.isnan(self._noted_s):
            key = check.value
            self.waited_s[key] = self.waited_s.get(key, 0.0) + now_s - self._noted_s
        self._noted_s = now_s

    def waits_line(self) -> str:
        """'driver 0.41 s, settle 0.30 s, ...': what the start waited for, in order."""
        return ", ".join(f"{k} {v:.2f} s" for k, v in self.waited_s.items()) or "nothing"

    def on_recorder_status(self, text: str, now_s: float) -> None:
        self.recorder_seen_s = now_s
        try:
            d = json.loads(text)
        except ValueError:
            return
        if not isinstance(d, dict):
            return
        if d.get("session") and d.get("path"):
            self.recorder_paths[str(d["session"])] = str(d["path"])
        got = d.get("receiving") or {}
        self.recorder_receiving = len(got) == 3 and min(got.values()) >= 0

    def on_stamp(self, topic: str, stamp_ns: int) -> None:
        self.stamps_ns[topic] = stamp_ns

    def silent_topics(self) -> list[str]:
        """The data topics besides the encoder whose samples do not keep up with it."""
        enc = self.stamps_ns.get("encoder")
        if enc is None:
            return []  # the encoder's own check comes first
        return [
            t
            for t in RECORDED_TOPICS
            if t != "encoder" and enc - self.stamps_ns.get(t, -(2**62)) > SAMPLES_STALE_S * 1e9
        ]

    def start_check(self, now_s: float, latency_ns: int, rules: StartRules) -> StartCheck:
        """The first start-up check not met yet (see the module docs)."""
        if self.driver is None:
            return StartCheck.DRIVER
        if now_s - self.last_sample_s > SAMPLES_STALE_S or self.silent_topics():
            return StartCheck.SAMPLES
        if latency_ns > rules.max_start_latency_s * 1e9:
            self.settled_since_s = math.inf  # still working through a backlog
            return StartCheck.LATENCY
        self.settled_since_s = min(self.settled_since_s, now_s)
        if now_s - self.settled_since_s < rules.settle_s:
            return StartCheck.SETTLE
        recorder_stale = now_s - self.recorder_seen_s > rules.peer_timeout_s
        # the recorder's subscriptions must match first: the driver's samples are
        # volatile, so any it missed before would be lost
        if rules.require_recorder and (recorder_stale or not self.recorder_receiving):
            return StartCheck.RECORDER
        return StartCheck.READY

    def refusal(self, now_s: float, latency_ns: int, rules: StartRules) -> str:
        """Why no session started within ``driver_wait_s``."""
        waited = f"{rules.driver_wait_s:g} s"
        if self.driver is None:
            return (
                f"no driver node {rules.driver_node!r} answered within {waited} "
                "(is it running, on this ROS_DOMAIN_ID?)"
            )
        if now_s - self.last_sample_s > SAMPLES_STALE_S:
            return f"the driver sent no samples within {waited}"
        if silent := self.silent_topics():
            return f"no samples on {' and '.join(silent)} within {waited} (encoder samples arrive)"
        if latency_ns > rules.max_start_latency_s * 1e9:
            return f"driver samples still arrive late after {waited}"
        if now_s - self.recorder_seen_s <= rules.peer_timeout_s:
            return f"the recorder received no driver samples within {waited}"
        return (
            f"no recorder within {waited} (start recorder_node, or run without "
            "a bag: -p require_recorder:=false)"
        )


@dataclass(frozen=True)
class SessionSettings:
    """The identification node's settings for one session (units in the names; a 0
    means 'derive it', as the node's parameter table says)."""

    nominal: MotorSpec
    sequence: SequenceConfig
    steady: SteadyStateConfig
    safe_mode: SafeMode
    tau_m_s: float
    rate_hz: float
    voltage_max_v: float
    current_max_a: float
    speed_max_rad_s: float
    stall_current_a: float
    stall_speed_rad_s: float
    stall_time_s: float
    data_timeout_s: float
    session_name: str

    def tau_s(self) -> float:
        return self.tau_m_s or self.nominal.model.params.mechanical_time_constant_s


def driver_limits(
    settings: SessionSettings, driver: Mapping[str, Any] | None
) -> tuple[Limits, float]:
    """The driver's trip limits (its parameters; 0 = its motor's limits) and its rate."""
    d = dict(driver or {})
    try:
        base = load_motor(d.get("motor") or settings.nominal.name).limits
    except PmdcError:
        base = settings.nominal.limits
    limits = Limits(
        voltage_max_v=d.get("voltage_limit_v") or base.voltage_max_v,
        current_max_a=d.get("current_limit_a") or base.current_max_a,
        speed_max_rad_s=d.get("speed_limit_rad_s") or base.speed_max_rad_s,
    )
    rate = float(settings.rate_hz or d.get("rate_hz") or 1000.0)
    return limits, rate


def safety_for(settings: SessionSettings, driver: Limits) -> SafetyConfig:
    """Abort thresholds: the settings where given, else derived from the driver's limits."""
    abort = Limits(
        voltage_max_v=driver.voltage_max_v,
        current_max_a=settings.current_max_a or ABORT_FRACTION * driver.current_max_a,
        speed_max_rad_s=settings.speed_max_rad_s or ABORT_FRACTION * driver.speed_max_rad_s,
    )
    safety = SafetyConfig.for_limits(
        abort,
        settings.tau_s(),
        stall_speed_rad_s=settings.stall_speed_rad_s,
        data_timeout_s=settings.data_timeout_s,
    )
    if settings.stall_current_a:
        safety = replace(safety, stall_current_a=settings.stall_current_a)
    if settings.stall_time_s:
        safety = replace(safety, stall_time_s=settings.stall_time_s)
    return safety


def plan_for(
    settings: SessionSettings, dt_s: float, safety: SafetyConfig, vmax: float
) -> TestPlan:
    limits = Limits(vmax, safety.current_max_a, safety.speed_max_rad_s)
    if settings.tau_m_s:
        return default_plan(dt_s, limits, settings.tau_m_s, settings.sequence)
    return plan_for_motor(replace(settings.nominal, limits=limits), dt_s, settings.sequence)


def build_session(
    settings: SessionSettings, driver: Mapping[str, Any] | None, name: str
) -> Session:
    """The session to run against this driver; :class:`PmdcError` when the plan would
    exceed a limit (nothing has moved then)."""
    limits, rate_hz = driver_limits(settings, driver)
    dt = 1.0 / rate_hz
    safety = safety_for(settings, limits)
    plan = plan_for(settings, dt, safety, settings.voltage_max_v or limits.voltage_max_v)
    nominal = settings.nominal if not settings.tau_m_s else None
    problems = check_plan(plan, limits, safety, nominal)
    if problems:
        raise PmdcError("plan refused before anything moved: " + "; ".join(problems))
    return Session(
        plan,
        safety,
        tau_m_s=settings.tau_s(),
        steady=settings.steady,
        safe_mode=settings.safe_mode,
        name=name,
    )
