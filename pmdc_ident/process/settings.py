"""The identification node's parameter values as the core's configuration (ROS-free).

The values are those of :data:`pmdc_ident.process.parameter_tables.IDENTIFICATION`,
by name; :func:`controller_config` builds the
:class:`~pmdc_ident.node_logic.session.controller.ControllerConfig` the node's
:class:`~pmdc_ident.node_logic.session.controller.SessionController` runs on, so the
controller is tested from the same table without ROS.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import fields
from typing import Any

from pmdc_ident.core.enums import SafeMode
from pmdc_ident.core.errors import OptionError, PmdcError, wording
from pmdc_ident.core.excitation import SequenceConfig
from pmdc_ident.core.fixed import parse_fix
from pmdc_ident.core.motors import load_motor
from pmdc_ident.node_logic.session.controller import ControllerConfig
from pmdc_ident.node_logic.session.ports import ExportRequest
from pmdc_ident.node_logic.session.sequential import PlanSetting
from pmdc_ident.node_logic.session.startup import SessionSettings, StartRules
from pmdc_ident.node_logic.session.steady_state import SteadyStateConfig
from pmdc_ident.process.identify_call import NODE_NAMES

__all__ = ["FLUSH_TIMEOUT_S", "controller_config"]

# longest wait for a session's last samples: the sample QoS buffer (10 s,
# pmdc_ident.nodes.qos.SAMPLE_BUFFER_S) and 5 s more
FLUSH_TIMEOUT_S = 15.0


def _dataclass(cls: Any, prefix: str, values: Mapping[str, Any]) -> Any:
    kwargs = {}
    for f in fields(cls):
        v = values[prefix + f.name]
        kwargs[f.name] = tuple(int(x) for x in v) if isinstance(v, list) else v
    try:
        return cls(**kwargs)
    except (PmdcError, TypeError) as exc:
        raise PmdcError(f"parameters {prefix}*: {exc}") from None


def controller_config(
    values: Mapping[str, Any], flush_timeout_s: float = FLUSH_TIMEOUT_S, namespace: str = ""
) -> ControllerConfig:
    """The controller's configuration from the node's parameter values (by table name);
    ``namespace`` is the node's (it names the sessions)."""
    try:
        nominal = load_motor(values["motor"])
    except PmdcError as exc:
        raise PmdcError(f"parameter motor: {exc}") from None
    try:
        with wording(NODE_NAMES):  # an error names the ROS parameter, not --fix
            fixed = parse_fix([s for s in values["fix"] if s])
    except OptionError as exc:
        raise PmdcError(exc.render(NODE_NAMES)) from None
    except PmdcError as exc:
        raise PmdcError(f"parameter fix: {exc}") from None
    v = values
    settings = SessionSettings(
        nominal=nominal,
        sequence=_dataclass(SequenceConfig, "sequence.", v),
        steady=_dataclass(SteadyStateConfig, "steady_state.", v),
        safe_mode=SafeMode(v["safe_mode"]),
        tau_m_s=float(v["tau_m_s"]),
        rate_hz=float(v["rate_hz"]),
        voltage_max_v=float(v["voltage_max_v"]),
        current_max_a=float(v["safety.current_max_a"]),
        speed_max_rad_s=float(v["safety.speed_max_rad_s"]),
        stall_current_a=float(v["safety.stall_current_a"]),
        stall_speed_rad_s=float(v["safety.stall_speed_rad_s"]),
        stall_time_s=float(v["safety.stall_time_s"]),
        data_timeout_s=float(v["safety.data_timeout_s"]),
        session_name=str(v["session_name"]),
    )
    return ControllerConfig(
        session=settings,
        start=StartRules(
            driver_node=str(v["driver_node"]),
            driver_wait_s=float(v["driver_wait_s"]),
            max_start_latency_s=float(v["max_start_latency_s"]),
            settle_s=float(v["settle_s"]),
            require_recorder=bool(v["require_recorder"]),
            peer_timeout_s=float(v["peer_timeout_s"]),
        ),
        confirm_timeout_s=float(v["confirm_timeout_s"]),
        exit_when_done=bool(v["exit_when_done"]),
        output_dir=str(v["output_dir"]),
        flush_timeout_s=flush_timeout_s,
        fixed=fixed,
        exports=_exports(v),
        namespace=namespace,
        plan=_plan(v),
    )


def _plan(v: Mapping[str, Any]) -> PlanSetting:
    try:
        return PlanSetting.from_values(v)
    except PmdcError as exc:
        raise PmdcError(f"parameter plan: {exc}") from None


def _exports(v: Mapping[str, Any]) -> ExportRequest | None:
    if not v["export_models"]:
        return None
    return ExportRequest(
        reduction=float(v["export_reduction"]),
        speed_bandwidth_hz=float(v["export_speed_bandwidth_hz"]),
        phase_margin_deg=float(v["export_phase_margin_deg"]),
    )
