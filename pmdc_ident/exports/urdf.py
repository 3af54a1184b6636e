"""The identified motor as a URDF joint and a ros2_control parameter file.

URDF (one output link on a continuous joint, as a snippet to merge into a robot):

* ``<dynamics damping friction>``: viscous and Coulomb friction reflected to the
  joint through the reduction N (``damping = B N^2`` N*m*s/rad, ``friction = Tc N``
  N*m);
* ``<limit effort velocity>``: the motor's current limit as output torque
  (``Kt I_max N``) and its speed limit at the output (``w_max / N``);
* ``<inertial>``: the rotor inertia reflected to the output (``J N^2`` about the
  joint axis, ``izz``) in a physically valid tensor: across the axis (``ixx = iyy``)
  the 7/6 of it of a solid cylinder as long as its diameter, so every triangle
  inequality (``ixx + iyy >= izz``, ...) holds with margin and simulators accept it
  (the mass, which no test measures, is a 1 g placeholder that adds no weight);
* a ROS 2 ``<ros2_control>`` block (no ROS 1 ``<transmission>``/
  ``hardware_interface/EffortJointInterface``): the joint with an effort command
  limited to the torque limit and position/velocity/effort state interfaces, and,
  inside it, the ``transmission_interface/SimpleTransmission`` with the reduction N
  (``<mechanical_reduction>``); replace its ``mock_components/GenericSystem`` plugin
  by your drive's.

ros2_control YAML (every value under a node's ``ros__parameters``, so any node loads
it with ``--params-file``): ``controller_manager`` (update rate = the gain design's
sample rate, the controllers' types, and the joint's ``joint_limits``, the layout
``joint_limits::get_joint_limits`` reads from a node's parameters), a
``joint_state_broadcaster``, a ``pid_controller/PidController`` closing the speed loop
on the joint's effort interface with the designed speed PI (converted to torque:
``Kt N`` times the current gains). The current loop lives in the drive (see
``export-model --gains``).

The joint's name (``joint``, default ``motor_joint``) is the driver node's
``joint_name`` default: a driver and the exports of its motor name the same joint.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

from pmdc_ident.core.control_design import GainDesign
from pmdc_ident.core.effects import CoulombFriction
from pmdc_ident.core.motors import MotorSpec

__all__ = ["CROSS_AXIS_RATIO", "JointFigures", "joint_figures", "ros2_control_yaml", "urdf_xml"]

# inertia across the axis / about it: a solid cylinder as long as its diameter,
# m (3 r^2 + h^2) / 12 over m r^2 / 2 with h = 2 r
CROSS_AXIS_RATIO = 7.0 / 6.0


class JointFigures:
    """The motor's figures at the joint (after the reduction), SI units."""

    def __init__(self, spec: MotorSpec, reduction: float) -> None:
        p, n = spec.model.params, float(reduction)
        coulomb = spec.model.effect("coulomb_friction")
        tc = coulomb.torque_nm if isinstance(coulomb, CoulombFriction) else 0.0
        self.reduction = n
        self.damping_nm_s_per_rad = p.B * n * n
        self.friction_nm = tc * n
        self.inertia_kg_m2 = p.J * n * n
        self.effort_max_nm = p.Kt * spec.limits.current_max_a * n
        self.velocity_max_rad_s = spec.limits.speed_max_rad_s / n
        self.torque_per_amp_nm = p.Kt * n


def joint_figures(spec: MotorSpec, reduction: float = 1.0) -> JointFigures:
    if not (math.isfinite(reduction) and reduction > 0):
        from pmdc_ident.core.errors import ParameterError  # noqa: PLC0415

        msg = f"gear reduction must be a positive number, got {reduction}"
        raise ParameterError(msg)
    return JointFigures(spec, reduction)


def urdf_xml(spec: MotorSpec, *, reduction: float = 1.0, joint: str = "motor_joint") -> str:
    """URDF text of the motor's joint (see module doc)."""
    fig = joint_figures(spec, reduction)
    robot = ET.Element("robot", name=f"{spec.name or 'pmdc_motor'}")
    ET.SubElement(robot, "link", name="base_link")
    out = ET.SubElement(robot, "link", name=f"{joint}_output")
    inertial = ET.SubElement(out, "inertial")
    ET.SubElement(inertial, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(inertial, "mass", value="1e-3")
    i_axis, i_across = _f(fig.inertia_kg_m2), _f(CROSS_AXIS_RATIO * fig.inertia_kg_m2)
    ET.SubElement(
        inertial, "inertia", ixx=i_across, ixy="0", ixz="0", iyy=i_across, iyz="0", izz=i_axis
    )
    j = ET.SubElement(robot, "joint", name=joint, type="continuous")
    ET.SubElement(j, "parent", link="base_link")
    ET.SubElement(j, "child", link=f"{joint}_output")
    ET.SubElement(j, "origin", xyz="0 0 0", rpy="0 0 0")
    ET.SubElement(j, "axis", xyz="0 0 1")
    ET.SubElement(j, "limit", effort=_f(fig.effort_max_nm), velocity=_f(fig.velocity_max_rad_s))
    ET.SubElement(
        j, "dynamics", damping=_f(fig.damping_nm_s_per_rad), friction=_f(fig.friction_nm)
    )
    _ros2_control_block(robot, joint, fig)
    tree = ET.ElementTree(robot)
    ET.indent(tree, space="  ")
    p = spec.model.params
    header = (
        '<?xml version="1.0"?>\n<!-- URDF written by pmdc-ident export-model from motor '
        f"'{spec.name}': R={p.R:.6g} ohm, Ke={p.Ke:.6g} V*s/rad, Kt={p.Kt:.6g} N*m/A, "
        f"J={p.J:.6g} kg*m^2, B={p.B:.6g} N*m*s/rad, reduction {fig.reduction:g}. "
        "Dynamics, limits and inertia are at the joint (after the reduction). -->\n"
    )
    return header + ET.tostring(robot, encoding="unicode") + "\n"


def _ros2_control_block(robot: ET.Element, joint: str, fig: JointFigures) -> None:
    rc = ET.SubElement(robot, "ros2_control", name=f"{joint}_system", type="system")
    hw = ET.SubElement(rc, "hardware")
    ET.SubElement(hw, "plugin").text = "mock_components/GenericSystem"
    jt = ET.SubElement(rc, "joint", name=joint)
    cmd = ET.SubElement(jt, "command_interface", name="effort")
    ET.SubElement(cmd, "param", name="min").text = _f(-fig.effort_max_nm)
    ET.SubElement(cmd, "param", name="max").text = _f(fig.effort_max_nm)
    for name in ("position", "velocity", "effort"):
        ET.SubElement(jt, "state_interface", name=name)
    tr = ET.SubElement(rc, "transmission", name=f"{joint}_transmission")
    ET.SubElement(tr, "plugin").text = "transmission_interface/SimpleTransmission"
    ET.SubElement(tr, "actuator", name=f"{joint}_motor", role="actuator1")
    tj = ET.SubElement(tr, "joint", name=joint, role="joint1")
    ET.SubElement(tj, "mechanical_reduction").text = _f(fig.reduction)


def ros2_control_yaml(
    spec: MotorSpec,
    design: GainDesign,
    *,
    reduction: float = 1.0,
    joint: str = "motor_joint",
) -> str:
    """A ros2_control parameter file for the joint (see module doc)."""
    fig = joint_figures(spec, reduction)
    # The speed PI outputs a current reference (A per rad/s at the motor); at the
    # joint it outputs torque: x Kt N for the torque, x N for the joint's speed.
    to_torque = fig.torque_per_amp_nm * fig.reduction
    pid = f"{joint}_speed_pid"
    data = {
        "controller_manager": {
            "ros__parameters": {
                "update_rate": int(round(design.sample_rate_hz)),
                "joint_state_broadcaster": {
                    "type": "joint_state_broadcaster/JointStateBroadcaster"
                },
                pid: {"type": "pid_controller/PidController"},
                "joint_limits": {
                    joint: {
                        "has_velocity_limits": True,
                        "max_velocity": fig.velocity_max_rad_s,
                        "has_effort_limits": True,
                        "max_effort": fig.effort_max_nm,
                    }
                },
            }
        },
        pid: {
            "ros__parameters": {
                "dof_names": [joint],
                "command_interface": "effort",
                "reference_and_state_interfaces": ["velocity"],
                "gains": {
                    joint: {
                        "p": design.speed_kp_a_s_per_rad * to_torque,
                        "i": design.speed_ki_a_per_rad * to_torque,
                        "d": 0.0,
                        "u_clamp_max": fig.effort_max_nm,
                        "u_clamp_min": -fig.effort_max_nm,
                        "antiwindup_strategy": "conditional_integration",
                    }
                },
            }
        },
    }
    p = spec.model.params
    header = (
        f"# ros2_control parameters written by pmdc-ident export-model from motor "
        f"'{spec.name}'.\n"
        f"# Speed PI for a {design.speed_crossover_hz:g} Hz crossover and "
        f"{design.speed_phase_margin_deg:.3g} deg phase margin at {design.sample_rate_hz:g} Hz,\n"
        f"# in joint torque (N*m per rad/s of joint speed); the drive closes the current loop\n"
        f"# (Kp {design.current_kp_v_per_a:.4g} V/A, "
        f"Ki {design.current_ki_v_per_as:.4g} V/(A*s)). "
        f"Kt={p.Kt:.6g} N*m/A, reduction {fig.reduction:g}.\n"
    )
    return header + yaml.safe_dump(data, sort_keys=False)


def write_text(path: str | Path, text: str) -> Path:
    from pmdc_ident.core import safe_write

    return safe_write.write_text(path, text)


def _f(x: float) -> str:
    return f"{x:.10g}"
