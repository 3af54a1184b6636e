"""The MuJoCo export carries the diagnosis: each effect's mapping replayed in MuJoCo."""

from __future__ import annotations

import json

import numpy as np
import pytest
from helpers.paths import REPO

from pmdc_ident.cli import main
from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis.scoring import NoiseModel
from pmdc_ident.core.effects import (
    BrushDrop,
    Cogging,
    CoulombFriction,
    Delay,
    LoadTorque,
    QuadraticDrag,
    ResistanceDrift,
    StribeckFriction,
)
from pmdc_ident.core.effects.resistance_drift import ALPHA_COPPER
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.model import Model, simulate
from pmdc_ident.core.motors import Limits, MotorSpec, load_motor
from pmdc_ident.core.params import MotorParams
from pmdc_ident.exports import write_exports
from pmdc_ident.exports.diagnosis import motor_with_diagnosis
from pmdc_ident.exports.mujoco_replay import SegmentStart, replay_segments
from pmdc_ident.exports.mujoco_xml import mapping_table, mujoco_xml
from pmdc_ident.exports.roundtrip import thermal_reference

mujoco = pytest.importorskip("mujoco")

P = MotorParams(R=2.0, L=2e-3, Ke=0.05, Kt=0.05, J=2e-5, B=2e-6)
T = P.Kt * 3.0  # about the rated torque
RATE = 1000.0
K = np.arange(3000)
V = np.concatenate(
    [
        np.full(600, 6.0),
        np.full(600, -9.0),
        4.0 * np.sin(2 * np.pi * 3 * K[:1200] / RATE),
        np.full(400, np.nan),
        np.full(200, 1.0),
    ]
)
LIMITS = Limits(voltage_max_v=20.0, current_max_a=30.0, speed_max_rad_s=1000.0)


def _errors(effect) -> tuple[float, float]:  # type: ignore[no-untyped-def]
    """MuJoCo's replay of the export against the project's model, and the effect's own
    size: RMS speed differences over the speed's RMS."""
    model = Model(P, (effect,))
    ref = simulate(model, V, 1 / RATE, substeps=64)
    lin = simulate(Model(P), V, 1 / RATE)
    ex = mujoco_xml(MotorSpec("t", model, limits=LIMITS), flavour="dcmotor", timestep_s=2e-5)
    seg = Segment(label="x", t=K / RATE, voltage=V, current=ref.current, position=ref.position,
                  speed=ref.speed)  # fmt: skip
    r = replay_segments(ex.xml, [seg], [SegmentStart(0.0, 0.0, 0.0)])[0]
    scale = float(np.sqrt(np.mean(ref.speed**2)))
    err = float(np.sqrt(np.mean((r.speed - ref.speed) ** 2))) / scale
    size = float(np.sqrt(np.mean((lin.speed - ref.speed) ** 2))) / scale
    return err, size


@pytest.mark.parametrize(
    ("effect", "share"),
    [
        (CoulombFriction(0.1 * T), 0.01),  # joint frictionloss
        (StribeckFriction(0.2 * T, 20.0, 2.0), 0.02),  # LuGre, Gaussian fall, no floor
        (StribeckFriction(0.2 * T, 20.0, 1.0), 0.03),  # ... the exponential one: 3 Gaussians
        (QuadraticDrag(0.1 * T / 1e4), 0.01),  # joint damping's quadratic term
        (LoadTorque(0.1 * T), 0.01),  # a passive dcmotor's zero-pole cogging
        (Cogging(0.1 * T, 7.0, 0.4), 0.03),  # dcmotor cogging, its sign as a phase
        (Delay(0.002, 0.0), 0.1),  # the actuator's ctrl history
        (ResistanceDrift(0.05, 3.0, 0.0), 0.1),  # dcmotor thermal
    ],
)
def test_each_carried_effect_replays_in_mujoco_as_in_the_project_s_model(effect, share):
    err, size = _errors(effect)
    assert size > 0.001  # the effect shows on this record ...
    assert err < share * size  # ... and MuJoCo carries it


@pytest.mark.parametrize(
    "effect",
    [
        Delay(0.0, 0.003),  # a drive's first-order lag alone
        (Delay(0.001, 0.002), StribeckFriction(0.1 * T, 20.0, 2.0)),  # friction beside it
    ],
)
def test_a_drive_s_first_order_lag_replays_in_mujoco_as_in_the_project_s_model(effect):
    # MuJoCo's delay is a transport delay; a lag is a drive joint whose speed is the
    # lagged voltage, the motor on a tendon whose back-EMF puts it across the winding
    # (written as a transport delay of its time constant, the current missed 66 % of
    # the lag's effect, the speed 41 %)
    effects = effect if isinstance(effect, tuple) else (effect,)
    model = Model(P, effects)
    pre = np.zeros(10)  # both from 0 V
    ref = simulate(model, V, 1 / RATE, substeps=64, pre_voltage=pre)
    lin = simulate(Model(P, effects[1:]), V, 1 / RATE, substeps=64, pre_voltage=pre)
    ex = mujoco_xml(MotorSpec("t", model, limits=LIMITS), flavour="dcmotor", timestep_s=2e-5)
    assert not any(line.startswith("delay") for line in ex.not_carried)
    seg = Segment(label="x", t=K / RATE, voltage=V, current=ref.current, speed=ref.speed,
                  history_voltage=pre)  # fmt: skip
    r = replay_segments(ex.xml, [seg], [SegmentStart(0.0, 0.0, 0.0)])[0]
    for sig in ("current", "speed"):
        got, want, plain = getattr(r, sig), getattr(ref, sig), getattr(lin, sig)
        size = float(np.sqrt(np.mean((plain - want) ** 2)))
        assert float(np.sqrt(np.mean((got - want) ** 2))) < 0.06 * size, sig


@pytest.mark.parametrize("shape", [2.0, 1.0])
def test_a_stribeck_stop_holds_the_rotor_in_mujoco_as_in_the_project_s_model(shape):
    # a heavy motor with a strong back-EMF (the 24 V scooter's fitted model) braked to a
    # stop: the project's model holds the rotor stuck; MuJoCo's LuGre bristles, 1e-4 rad
    # soft, rang against the rotor there (9 % of the friction's effect on the current,
    # its noise's size on the scooter's held-out step down); as stiff as the step
    # resolves, they hold it (an exponential fall as four Gaussian falls: 1.6 %, not 3.4 %)
    p = MotorParams(R=0.34, L=6e-4, Ke=0.73, Kt=0.73, J=0.05, B=0.02)
    rate, pre = 500.0, np.zeros(4)
    v = np.concatenate([np.full(100, 4.0), np.zeros(150)])
    model = Model(p, (StribeckFriction(5.0, 1.8, shape),))
    ref = simulate(model, v, 1 / rate, substeps=64, pre_voltage=pre)
    lin = simulate(Model(p), v, 1 / rate, substeps=64, pre_voltage=pre)
    assert (ref.speed == 0.0).sum() > 100  # stuck for most of the 0 V part
    limits = Limits(voltage_max_v=30.0, current_max_a=100.0, speed_max_rad_s=100.0)
    ex = mujoco_xml(MotorSpec("t", model, limits=limits), flavour="dcmotor",
                    timestep_s=1 / rate / 50)  # fmt: skip
    seg = Segment(label="x", t=np.arange(v.size) / rate, voltage=v, current=ref.current,
                  speed=ref.speed, history_voltage=pre)  # fmt: skip
    r = replay_segments(ex.xml, [seg], [SegmentStart(0.0, 0.0, 0.0)])[0]
    for sig in ("current", "speed"):
        got, want, plain = getattr(r, sig), getattr(ref, sig), getattr(lin, sig)
        size = float(np.sqrt(np.mean((plain - want) ** 2)))
        assert float(np.sqrt(np.mean((got - want) ** 2))) < 0.03 * size, sig


def test_a_heated_winding_replays_with_mujoco_s_inductance_exact_at_the_thermal_reference():
    # MuJoCo keeps L/R as its winding heats (its L rises with R); the model's L does
    # not. Written at the rise that replays the fit's record best in MuJoCo (chosen on
    # that record only), MuJoCo's L is the winding's where the record needs it: a fast
    # sine on a warm winding replays close to the project's model; written at ambient,
    # MuJoCo's L is (1 + alpha T) too large
    rate, k = 2000.0, np.arange(4000)
    v = np.concatenate([np.full(2000, 8.0), 8.0 + 3.0 * np.sin(2 * np.pi * 150 * k[:2000] / rate)])
    model = Model(P, (ResistanceDrift(0.25, 3.0, 0.0),))
    ref = simulate(model, v, 1 / rate, substeps=64)
    lin = simulate(Model(P), v, 1 / rate)
    seg = Segment(label="x", t=k / rate, voltage=v, current=ref.current, position=ref.position,
                  speed=ref.speed)  # fmt: skip
    spec = MotorSpec("t", model, limits=LIMITS)
    scale = {"current": float(np.sqrt(np.mean(ref.current**2))),
             "speed": float(np.sqrt(np.mean(ref.speed**2)))}  # fmt: skip
    noise = NoiseModel({s: 0.01 * x for s, x in scale.items()}, scale)
    rise = thermal_reference(spec, [seg], noise, timestep_s=2.5e-5, tau_s=0.01)
    assert 0.05 < ALPHA_COPPER * rise < 0.15  # the winding warms 5-15 % over the sine
    assert thermal_reference(MotorSpec("t", Model(P), limits=LIMITS), [seg], noise,
                             timestep_s=2.5e-5, tau_s=0.01) == 0.0  # fmt: skip

    def current_error(reference_k: float) -> float:
        ex = mujoco_xml(MotorSpec("t", model, limits=LIMITS), flavour="dcmotor",
                        timestep_s=2.5e-5, thermal_reference_k=reference_k)  # fmt: skip
        r = replay_segments(ex.xml, [seg], [SegmentStart(0.0, 0.0, 0.0)])[0]
        return float(np.sqrt(np.mean((r.current - ref.current)[2000:] ** 2)))

    size = float(np.sqrt(np.mean((lin.current - ref.current)[2000:] ** 2)))
    at_reference, at_ambient = current_error(rise), current_error(0.0)
    assert at_reference < 0.4 * size  # carried (31 % of the effect's size left)
    assert at_ambient > 0.7 * size  # ... where L at ambient leaves most of it (85 %)
    with pytest.raises(ParameterError):
        mujoco_xml(MotorSpec("t", model, limits=LIMITS), thermal_reference_k=-1.0)


def test_what_mujoco_cannot_carry_is_listed_with_the_part_left_out():
    model = Model(P, (BrushDrop(0.3), Delay(0.001, 0.0005), ResistanceDrift(0.05, 3.0, 0.2)))
    ex = mujoco_xml(MotorSpec("t", model, limits=LIMITS), flavour="dcmotor")
    assert any(line.startswith("brush_drop: brush voltage drop") for line in ex.not_carried)
    assert not any(line.startswith("delay") for line in ex.not_carried)  # the lag too
    assert any(line.startswith("resistance_drift: the magnets' flux") for line in ex.not_carried)
    assert [c.split(":")[0] for c in ex.carried] == ["delay", "resistance_drift"]
    m = mujoco.MjModel.from_xml_string(ex.xml)
    # the transport delay on the drive that takes the command, the lag its joint's
    assert m.actuator_ctrlnum.tolist() == [0, 1] and m.actuator_delay[1] == pytest.approx(0.001)
    assert m.dof_armature[1] / m.dof_damping[1] == pytest.approx(0.0005)
    # an exponential Stribeck fall goes in as MuJoCo's Gaussian one: carried, and said so
    expo = Model(P, (StribeckFriction(0.2 * T, 20.0, 1.0),))
    ex1 = mujoco_xml(MotorSpec("t", expo, limits=LIMITS), flavour="dcmotor")
    assert [c.split(":")[0] for c in ex1.carried] == ["stribeck_friction"]
    assert any(line.startswith("stribeck_friction: the exponential") for line in ex1.not_carried)
    # ... as four Gaussian falls on four LuGre elements whose static levels add up to
    # the breakaway torque, with no Coulomb level the model does not have (a floor only)
    m1 = mujoco.MjModel.from_xml_string(ex1.xml)
    assert m1.nu == 1 and m1.nu + 3 == m1.actuator_biasprm.shape[0]
    static = m1.actuator_biasprm[:, 4].sum()  # lugre's static level per element
    assert static == pytest.approx(0.2 * T, rel=1e-5)
    assert m1.actuator_biasprm[:, 3].sum() < 1e-5 * T  # Coulomb levels: floors only
    gauss = Model(P, (StribeckFriction(0.2 * T, 20.0, 2.0),))
    ex2 = mujoco_xml(MotorSpec("t", gauss, limits=LIMITS), flavour="dcmotor")
    assert not any(line.startswith("stribeck_friction") for line in ex2.not_carried)
    # general actuators (MuJoCo < 4) carry the joint's terms only
    gen = mujoco_xml(MotorSpec("t", model, limits=LIMITS), flavour="general")
    assert not gen.carried and "needs MuJoCo >= 4" in " ".join(gen.not_carried)


def test_kt_unequal_ke_is_said_not_carried():
    p = MotorParams(R=2.0, L=2e-3, Ke=0.05, Kt=0.055, J=2e-5, B=2e-6)
    ex = mujoco_xml(MotorSpec("t", Model(p), limits=LIMITS), flavour="dcmotor")
    assert any(line.startswith("Kt != Ke") for line in ex.not_carried)
    assert not any(
        line.startswith("Kt != Ke")
        for line in mujoco_xml(MotorSpec("t", Model(P), limits=LIMITS)).not_carried
    )


def _diagnosis(spec: MotorSpec, effects: dict[str, dict[str, float]], status: str = "explained"):  # type: ignore[no-untyped-def]
    p = spec.model.params
    params = {k: {"value": v} for k, v in p.as_dict().items()}
    for name, fields in effects.items():
        params.update({f"{name}.{f}": {"value": v} for f, v in fields.items()})
    return {"verdict": {"status": status, "effects": list(effects)}, "parameters": params}


def test_export_model_takes_a_diagnosis_and_writes_every_effect_mujoco_carries(tmp_path, capsys):
    spec = load_motor("seed000_ebike")
    doc = _diagnosis(
        spec,
        {
            "cogging": {"torque_nm": 0.01, "periods_per_rev": 14.0, "phase_rad": 0.3},
            "resistance_drift": {"coeff_per_a2s": 0.002, "time_constant_s": 30.0},
            "brush_drop": {"voltage_v": 0.4},
        },
    )
    diag = tmp_path / "diag.json"
    diag.write_text(json.dumps(doc))
    out = tmp_path / "m.xml"
    assert main(["export-model", "seed000_ebike", "--mujoco", str(out), "--diagnosis",
                 str(diag)]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert "carried: cogging" in text and "carried: resistance_drift" in text
    assert "not carried: brush_drop" in text
    m = mujoco.MjModel.from_xml_path(str(out))
    assert m.actuator_biasprm[0, :2] == pytest.approx([0.01, 14.0])
    assert m.actuator_dynprm[0, 2] > 0  # a thermal state
    assert m.dof_frictionloss[0] == 0.0  # the diagnosis' model has no Coulomb friction
    # the motor file's Coulomb friction is the diagnosis' model's to keep or leave
    assert "coulomb_friction is left out" in text


def test_export_model_refuses_a_diagnosis_of_another_motor_or_no_diagnosis(tmp_path, capsys):
    spec = load_motor("seed000_ebike")
    other = MotorSpec("o", Model(P.replace(Ke=0.5, Kt=0.5)))
    bad = tmp_path / "other.json"
    bad.write_text(json.dumps(_diagnosis(other, {"load_torque": {"torque_nm": 0.1}})))
    out = tmp_path / "m.xml"
    assert main(["export-model", "seed000_ebike", "--mujoco", str(out), "--diagnosis",
                 str(bad)]) == 2  # fmt: skip
    assert "not one motor" in capsys.readouterr().err
    junk = tmp_path / "junk.json"
    junk.write_text("{not json")
    assert main(["export-model", "seed000_ebike", "--mujoco", str(out), "--diagnosis",
                 str(junk)]) == 2  # fmt: skip
    assert main(["export-model", "seed000_ebike", "--diagnosis", str(bad)]) == 2
    assert "give --mujoco" in capsys.readouterr().err
    assert not out.exists()
    # a diagnosis that names nothing exports the motor file as it is
    none = tmp_path / "none.json"
    none.write_text(json.dumps(_diagnosis(spec, {}, status="no_gap")))
    assert main(["export-model", "seed000_ebike", "--mujoco", str(out), "--diagnosis",
                 str(none)]) == 0  # fmt: skip
    m = mujoco.MjModel.from_xml_path(str(out))
    assert m.dof_frictionloss[0] == pytest.approx(0.0256)


def test_write_exports_puts_the_diagnosis_into_the_mjcf_beside_the_bag(tmp_path):
    spec = load_motor("seed000_ebike")
    doc = _diagnosis(spec, {"quadratic_drag": {"coeff_nm_s2": 1e-6}})
    paths = write_exports(spec, tmp_path, stem="identified", diagnosis=doc)
    m = mujoco.MjModel.from_xml_path(str(paths[0]))
    assert m.dof_damping[0] == pytest.approx(spec.model.params.B)
    assert "quadratic_drag" in paths[0].read_text().split("-->")[0]
    assert motor_with_diagnosis(spec, doc).effects == ("quadratic_drag",)


def test_the_mapping_table_in_docs_is_the_registry_s():
    assert mapping_table() in (REPO / "docs" / "mujoco.md").read_text()
