"""The plan check: reasons a test plan must not run, found before anything moves."""

from __future__ import annotations

import numpy as np

from pmdc_ident.core.excitation import TestPlan
from pmdc_ident.core.motors import Limits, MotorSpec
from pmdc_ident.core.safety import SafetyConfig

__all__ = ["check_plan"]


def check_plan(
    plan: TestPlan,
    driver_limits: Limits,
    safety: SafetyConfig,
    nominal: MotorSpec | None = None,
) -> list[str]:
    """Reasons the plan must not run (empty: fine). Checked before anything moves."""
    problems: list[str] = []
    v_all = np.concatenate([s.voltage for s in plan.segments])
    v_max = float(np.nanmax(np.abs(v_all))) if np.isfinite(v_all).any() else 0.0
    if v_max > driver_limits.voltage_max_v * (1 + 1e-9):
        problems.append(
            f"plan needs {v_max:.3g} V but the driver's voltage limit is "
            f"{driver_limits.voltage_max_v:.3g} V"
        )
    if safety.current_max_a > driver_limits.current_max_a * (1 + 1e-9):
        problems.append(
            f"session current abort {safety.current_max_a:.3g} A is above the driver's "
            f"current limit {driver_limits.current_max_a:.3g} A"
        )
    if safety.speed_max_rad_s > driver_limits.speed_max_rad_s * (1 + 1e-9):
        problems.append(
            f"session speed abort {safety.speed_max_rad_s:.4g} rad/s is above the driver's "
            f"speed limit {driver_limits.speed_max_rad_s:.4g} rad/s"
        )
    if nominal is not None:
        p = nominal.model.params
        i_ss, w_ss = p.steady_state(v_max)
        if abs(w_ss) > safety.speed_max_rad_s:
            problems.append(
                f"nominal motor would reach {w_ss:.4g} rad/s at {v_max:.3g} V, above the "
                f"speed abort {safety.speed_max_rad_s:.4g} rad/s: lower the voltage fractions"
            )
        if abs(i_ss) > safety.current_max_a:
            problems.append(
                f"nominal motor would draw {i_ss:.3g} A steadily at {v_max:.3g} V, above "
                f"the current abort {safety.current_max_a:.3g} A"
            )
    return problems
