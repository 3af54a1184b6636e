"""``plan: auto`` end to end over DDS (issue 25): driver, recorder and identification
node as separate processes; a geared joint (the benchmark's 100:1 gearmotor with
Coulomb friction) that may turn only +-2 rad. The node runs the pre-test, has the plan
designed, re-fits as segments finish and stops at the target; the measured position
never leaves the range."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from pmdc_ident.benchmark.motors import MOTORS
from pmdc_ident.dataio.bagio import read_driver_arrays
from pmdc_ident.process.bringup import run_session

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def joint_motor(path: Path) -> Path:
    """The 100:1 gearmotor at its output shaft, with Coulomb friction (half its no-load
    friction torque), as a motor file the simulated driver runs."""
    m = MOTORS["gearmotor_12v"]
    p = m.params
    tc = 0.5 * p.Kt * 2.0 * p.B * m.speed_no_load_rad_s / p.Kt
    doc = {
        "name": "joint_gearmotor",
        "description": "12 V 100:1 gearmotor at its output (pmdc_ident/benchmark/motors.py)",
        "parameters": p.as_dict(),
        "effects": {"coulomb_friction": {"torque_nm": tc}},
        "sensors": {
            "current_noise_a": 0.008,
            "speed_noise_rad_s": 0.02,
            "encoder_counts_per_rev": m.counts_per_rev,
        },
        "limits": {
            "voltage_max_v": m.voltage_rated_v,
            "current_max_a": 1.5 * m.voltage_rated_v / p.R,
            "speed_max_rad_s": 2.0 * m.speed_no_load_rad_s,
        },
    }
    path.write_text(yaml.safe_dump(doc))
    return path


LATE = re.compile(r"ABORTED \(out_of_travel\).*up to ([0-9.]+) s late just before, beyond")


def _joint_session(tmp_path: Path, ros_domain: int, run: str, command_delay_s: float):  # type: ignore[no-untyped-def]
    return run_session(
        output_dir=tmp_path / run / "out",
        motor=str(joint_motor(tmp_path / "joint.yaml")),
        domain_id=ros_domain,
        identification_params={
            "plan": "auto",
            "plan_travel_rad": [-2.0, 2.0],
            "plan_budget_s": 10.0,
            "plan_heat_a2s": 1.0,
            "plan_command_delay_s": command_delay_s,
            "safety.data_timeout_s": 1.5,
        },
        driver_params={"watchdog_s": 1.5},
        log_dir=tmp_path / run / "logs",
        timeout_s=240.0,
    )


def test_a_travel_limited_joint_is_identified_to_the_target_without_leaving_its_range(
    tmp_path, ros_domain
):
    res = _joint_session(tmp_path, ros_domain, "first", 0.15)
    late = LATE.search(res.logs["identification"].read_text())
    if res.identification_rc == 3 and late:
        # The plan keeps the joint inside for commands up to 0.15 s late. A host starved
        # beyond that (CI beside two CPU hogs) let the joint reach its end, the travel
        # rule stopped it, and the node's line measured the lateness. That breaks this
        # test's premise, not the session: run it once more as it was. An abort without
        # that lateness, or a second abort, fails. (Raising plan_command_delay_s, the
        # node's advice to a user, changes the plan: at 0.3 s the design leaves B out of
        # its target, at 0.6 s it had not met it after 240 s.)
        print(f"first session aborted out of travel, samples {late.group(1)} s late: re-run")
        res = _joint_session(tmp_path, ros_domain, "again", 0.15)
    logs = "\n".join(p.read_text()[-3000:] for p in res.logs.values())
    assert res.identification_rc == 0, logs
    design = res.result["experiment_design"]
    rounds = design["rounds"]
    assert rounds[-1]["action"] == "stop", rounds
    assert rounds[-1]["message"].startswith("target met"), rounds
    # within the motor time it was given; on a joint every part is re-designed from the
    # fit so far, so the first plan's total is a forecast, printed for the record (the
    # 10 % goal is checked where the motor turns freely: test_session_plan_auto)
    assert design["motor_s"] <= 10.0 + 1e-6, design
    redesigned = res.logs["identification"].read_text().count("re-designing from there")
    print(
        f"motor time {design['motor_s']:.3g} s, first plan {design['planned_s']:.3g} s, "
        f"{redesigned} extension(s) re-designed for the joint's rest position"
    )
    arrays = read_driver_arrays(res.bag)
    assert arrays.position_rad.size > 100
    assert -2.0 <= float(arrays.position_rad.min()) and float(arrays.position_rad.max()) <= 2.0
    params = res.result["parameters"]
    for name, target in (("R", 0.01), ("Ke", 0.01), ("J", 0.01), ("B", 0.01)):
        e = params[name]
        assert e["stderr"] / e["value"] <= target, (name, e)
    tc = params["coulomb_friction.torque_nm"]
    assert tc["stderr"] / tc["value"] <= 0.05
    truth = MOTORS["gearmotor_12v"].params
    assert params["R"]["value"] == pytest.approx(truth.R, rel=0.03)
    assert params["J"]["value"] == pytest.approx(truth.J, rel=0.03)
    assert math.isfinite(float(np.median(arrays.current_a)))
    json.dumps(design)
