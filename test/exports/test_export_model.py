"""export-model: MJCF replayed in MuJoCo, URDF parsed by ROS's parser, gains closed on a plant."""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import yaml

from pmdc_ident.cli import main
from pmdc_ident.core.control_design import (
    TOLERANCES,
    ControlDesignError,
    check_gains,
    design_gains,
)
from pmdc_ident.core.effects import BrushDrop, CoulombFriction
from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
from pmdc_ident.core.model import Model, simulate_linear
from pmdc_ident.core.motors import MotorSpec, load_motor
from pmdc_ident.exports.mujoco_xml import mujoco_xml
from pmdc_ident.exports.urdf import ros2_control_yaml, urdf_xml

mujoco = pytest.importorskip("mujoco")


def _linear(spec: MotorSpec) -> MotorSpec:
    return MotorSpec(spec.name, Model(spec.model.params), spec.sensors, spec.limits)


def _recorded_voltage(spec: MotorSpec, dt_s: float) -> np.ndarray:
    """The commanded voltage of a simulated session, without the open-armature coast."""
    run = synthesize_run(spec.model, plan_for_motor(spec, dt_s), spec.sensors, seed=3)
    return np.concatenate([s.voltage for s in run.segments if not np.isnan(s.voltage).any()])


def _replay(xml: str, voltage: np.ndarray, dt_s: float, reduction: float) -> np.ndarray:
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    sub = round(dt_s / m.opt.timestep)
    w = np.empty(voltage.size)
    for k, v in enumerate(voltage):
        w[k] = d.qvel[0] * reduction  # motor speed
        d.ctrl[0] = v
        mujoco.mj_step(m, d, nstep=sub)
    return w


@pytest.mark.parametrize(
    ("motor", "flavour", "reduction"),
    [
        ("seed000_ebike", "dcmotor", 1.0),
        ("seed001_110v", "dcmotor", 12.0),
        ("seed000_ebike", "general", 3.0),
    ],
)
def test_mujoco_replay_of_a_recorded_voltage_matches_the_linear_model_within_1pct(
    motor: str, flavour: str, reduction: float
) -> None:
    spec = _linear(load_motor(motor))
    dt = 1e-3
    v = _recorded_voltage(spec, dt)[:20000]
    ex = mujoco_xml(spec, flavour=flavour, reduction=reduction)
    w_mj = _replay(ex.xml, v, dt, reduction)
    w_ref = simulate_linear(spec.model.params, v, dt).speed
    rel_rms = np.sqrt(np.mean((w_mj - w_ref) ** 2)) / np.sqrt(np.mean(w_ref**2))
    assert rel_rms < 0.01, rel_rms
    assert ex.flavour == flavour


def test_mujoco_export_carries_friction_and_names_what_it_cannot() -> None:
    spec = load_motor("seed000_ebike")
    tc = spec.model.effect("coulomb_friction")
    assert isinstance(tc, CoulombFriction)
    model = spec.model.with_effects(BrushDrop(0.5))
    spec = MotorSpec(spec.name, model, spec.sensors, spec.limits)
    ex = mujoco_xml(spec, reduction=4.0)
    m = mujoco.MjModel.from_xml_string(ex.xml)
    assert m.dof_frictionloss[0] == pytest.approx(tc.torque_nm * 4.0)
    assert m.dof_damping[0] == pytest.approx(spec.model.params.B * 16.0)
    assert m.dof_armature[0] == pytest.approx(spec.model.params.J * 16.0)
    assert any(item.startswith("brush_drop") for item in ex.not_carried)
    assert "brush_drop" in ex.xml.split("-->")[0]
    assert not any(item.startswith("coulomb") for item in ex.not_carried)


def test_mujoco_xml_is_written_without_the_mujoco_package(tmp_path) -> None:
    code = (
        "import sys; sys.modules['mujoco'] = None\n"
        "from pmdc_ident.core.motors import load_motor\n"
        "from pmdc_ident.exports.mujoco_xml import mujoco_xml\n"
        "ex = mujoco_xml(load_motor('seed000_ebike'))\n"
        "print(ex.flavour, '<dcmotor' in ex.xml)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["dcmotor", "True"]


def test_urdf_parses_with_dynamics_limits_and_reduction() -> None:
    urdf = pytest.importorskip("urdf_parser_py.urdf")
    spec = load_motor("seed000_ebike")
    p = spec.model.params
    robot = urdf.URDF.from_xml_string(urdf_xml(spec, reduction=10.0, joint="wheel"))
    j = robot.joint_map["wheel"]
    assert j.dynamics.damping == pytest.approx(p.B * 100)
    assert j.dynamics.friction == pytest.approx(0.0256 * 10)
    assert j.limit.effort == pytest.approx(p.Kt * spec.limits.current_max_a * 10)
    assert j.limit.velocity == pytest.approx(spec.limits.speed_max_rad_s / 10)
    inertia = robot.link_map["wheel_output"].inertial.inertia
    assert inertia.izz == pytest.approx(p.J * 100)


def test_urdf_inertia_is_physically_valid_and_the_transmission_is_ros2_control() -> None:
    """Every triangle inequality of the principal moments holds (simulators refuse a
    tensor that breaks one), and the reduction rides in a ROS 2 <ros2_control>
    transmission, not a ROS 1 <transmission> with EffortJointInterface (issue 24)."""
    urdf = pytest.importorskip("urdf_parser_py.urdf")
    for reduction in (1.0, 10.0, 0.25):
        text = urdf_xml(load_motor("seed000_ebike"), reduction=reduction, joint="wheel")
        inertia = urdf.URDF.from_xml_string(text).link_map["wheel_output"].inertial.inertia
        moments = np.array([inertia.ixx, inertia.iyy, inertia.izz])
        assert np.all(moments > 0) and inertia.ixy == inertia.ixz == inertia.iyz == 0
        for k in range(3):
            assert moments.sum() - moments[k] >= 1.1 * moments[k], (reduction, moments)
        root = ET.fromstring(text)
        assert root.find("transmission") is None  # the ROS 1 form is gone
        assert "EffortJointInterface" not in text
        (tr,) = root.findall("ros2_control/transmission")
        assert tr.findtext("plugin") == "transmission_interface/SimpleTransmission"
        assert tr.find("joint").get("name") == "wheel"
        assert float(tr.findtext("joint/mechanical_reduction")) == pytest.approx(reduction)
        assert root.find("ros2_control/joint").get("name") == "wheel"


def test_ros2_control_yaml_loads_with_params_file_in_a_node(tmp_path) -> None:
    """Every value under a node's ros__parameters: rcl parses the file at start-up
    (a top-level block failed: 'Cannot have a value before ros__parameters', issue 24)
    and the controller_manager node gets the joint's limits."""
    rclpy = pytest.importorskip("rclpy")
    from rclpy.context import Context

    spec = load_motor("seed000_ebike")
    d = design_gains(spec.model.params, spec.limits, sample_rate_hz=500, speed_bandwidth_hz=4)
    path = tmp_path / "wheel.ros2_control.yaml"
    path.write_text(ros2_control_yaml(spec, d, reduction=5.0, joint="wheel"))
    data = yaml.safe_load(path.read_text())
    assert all(set(v) == {"ros__parameters"} for v in data.values()), data.keys()
    ctx = Context()
    rclpy.init(args=["--ros-args", "--params-file", str(path)], context=ctx)
    try:
        node = rclpy.create_node(
            "controller_manager",
            context=ctx,
            automatically_declare_parameters_from_overrides=True,
        )
        got = {k: v.value for k, v in node.get_parameters_by_prefix("").items()}
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    assert got["update_rate"] == 500
    assert got["joint_limits.wheel.max_effort"] == pytest.approx(spec.model.params.Kt * 30 * 5)
    assert got["wheel_speed_pid.type"] == "pid_controller/PidController"


def test_ros2_control_yaml_holds_the_speed_pi_as_joint_torque() -> None:
    spec = load_motor("seed000_ebike")
    d = design_gains(spec.model.params, spec.limits, sample_rate_hz=500, speed_bandwidth_hz=4)
    data = yaml.safe_load(ros2_control_yaml(spec, d, reduction=5.0, joint="wheel"))
    assert data["controller_manager"]["ros__parameters"]["update_rate"] == 500
    gains = data["wheel_speed_pid"]["ros__parameters"]["gains"]["wheel"]
    kt = spec.model.params.Kt
    assert gains["p"] == pytest.approx(d.speed_kp_a_s_per_rad * kt * 25)
    assert gains["i"] == pytest.approx(d.speed_ki_a_per_rad * kt * 25)
    limits = data["controller_manager"]["ros__parameters"]["joint_limits"]["wheel"]
    assert limits["max_effort"] == pytest.approx(kt * 30 * 5)


def test_gains_meet_their_promise_on_the_true_motor_when_designed_on_an_imperfect_model() -> None:
    true = load_motor("seed000_ebike")
    p = true.model.params
    # What an identification might return: a few per cent off, friction unmodelled.
    ident = MotorSpec(
        "identified",
        Model(p.replace(R=p.R * 1.03, J=p.J * 0.95, B=p.B * 1.2, Ke=p.Ke * 0.98, Kt=p.Kt * 0.98)),
        limits=true.limits,
    )
    d = design_gains(ident.model.params, ident.limits, sample_rate_hz=1000, speed_bandwidth_hz=5)
    assert d.speed_phase_margin_deg == pytest.approx(60.0, abs=0.5)
    assert d.current_phase_margin_deg == pytest.approx(60.0, abs=0.5)
    checks = check_gains(d, ident, [true])
    assert [c.plant for c in checks] == ["identified linear model", "seed000_ebike"]
    for c in checks:
        assert c.ok, c
        assert c.peak_voltage_v < true.limits.voltage_max_v
    # The promise is a real bound: the discrete loop is close to the design loop.
    assert abs(checks[0].measured.overshoot_pct - d.promised.overshoot_pct) < 2.0
    assert checks[0].measured.settling_s < d.promised.settling_s * TOLERANCES["settling_factor"]


def test_gains_refuse_a_bandwidth_the_sample_rate_cannot_carry() -> None:
    spec = load_motor("seed000_ebike")
    with pytest.raises(ControlDesignError, match="at most"):
        design_gains(
            spec.model.params,
            spec.limits,
            sample_rate_hz=1000,
            speed_bandwidth_hz=5,
            current_bandwidth_hz=200,
        )
    with pytest.raises(ControlDesignError, match="quarter"):
        design_gains(spec.model.params, spec.limits, sample_rate_hz=200, speed_bandwidth_hz=5)


def test_cli_writes_every_export_and_reports_the_checks(tmp_path, capsys) -> None:
    out = {k: tmp_path / f"m.{k}" for k in ("xml", "urdf", "rc.yaml", "gains.yaml")}
    rc = main(
        [
            "export-model",
            "seed000_ebike",
            "--mujoco",
            str(out["xml"]),
            "--urdf",
            str(out["urdf"]),
            "--ros2-control",
            str(out["rc.yaml"]),
            "--gains",
            str(out["gains.yaml"]),
            "--verify-on",
            "seed000_ebike",
        ]
    )
    text = capsys.readouterr().out
    assert rc == 0, text
    assert all(p.is_file() for p in out.values())
    assert "not carried: open armature" in text
    gains = yaml.safe_load(out["gains.yaml"].read_text())
    assert all(v["within_promise"] for v in gains["verification"])
    mujoco.MjModel.from_xml_path(str(out["xml"]))
    rc = main(
        [
            "export-model",
            "seed000_ebike",
            "--gains",
            str(out["gains.yaml"]),
            "--speed-bandwidth-hz",
            "50",
        ]
    )
    assert rc == 2
    assert "error: speed bandwidth 50 Hz" in capsys.readouterr().err


def test_exports_are_importable_from_the_package() -> None:
    from pmdc_ident import design_gains as dg
    from pmdc_ident import load_motor as lm
    from pmdc_ident import mujoco_xml as mx
    from pmdc_ident import urdf_xml as ux

    spec = lm("seed001_110v")
    assert "<dcmotor" in mx(spec).xml
    assert "<ros2_control" in ux(spec)
    design = dg(spec.model.params, spec.limits, sample_rate_hz=1000, speed_bandwidth_hz=3)
    assert design.speed_phase_margin_deg >= 59.5


def test_cli_refuses_a_wrong_output_name_before_any_work(tmp_path, capsys) -> None:
    rc = main(["export-model", "seed000_ebike", "--mujoco", str(tmp_path / "m.txt")])
    assert rc == 2
    assert "--mujoco" in capsys.readouterr().err
    assert main(["export-model", "seed000_ebike", "--urdf", str(tmp_path / "no" / "m.urdf")]) == 2


def test_write_exports_puts_every_format_beside_a_result(tmp_path) -> None:
    from pmdc_ident import write_exports

    paths = write_exports(load_motor("seed000_ebike"), tmp_path, stem="identified")
    assert [p.name for p in paths] == [
        "identified.mjcf.xml",
        "identified.urdf",
        "identified.ros2_control.yaml",
        "identified.gains.yaml",
    ]
    mujoco.MjModel.from_xml_path(str(paths[0]))
    gains = yaml.safe_load(paths[3].read_text())
    assert all(v["within_promise"] for v in gains["verification"])
