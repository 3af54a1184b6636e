"""Five benchmark motors, 0.45 W to 1.1 kW, direct and geared, with their drivers.

Every motor is described at the shaft the encoder of its driver measures (the
output shaft of a gearbox), in SI units; the parameters come from the datasheet
figures a user has (rated voltage, stall current, no-load speed and current,
rotor inertia, terminal inductance) by the usual relations:

* ``R = V_rated / I_stall``; ``Ke = Kt = (V_rated - R I_0) / w_0`` (SI, so Kt = Ke);
* viscous ``B``: half the no-load friction torque ``Kt I_0`` at ``w_0`` (the other
  half of a real no-load current is Coulomb friction, which the benchmark adds as
  an effect, so effect-free runs carry viscous friction only);
* geared motors: ``Ke``, ``Kt`` times the ratio ``N``, rotor inertia times ``N^2``,
  encoder counts per output turn times ``N``; plus the load's inertia;
* rated torque ``T_rated = Kt I_rated`` (continuous), the unit of torque effects.

The figures are those of common motor classes (catalogue values rounded), not
of one product; ``SOURCES`` says which class each motor stands for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pmdc_ident.core.params import MotorParams

__all__ = ["ALL_MOTORS", "MOTORS", "MUJOCO_MOTORS", "BenchMotor", "DriverSensors"]


@dataclass(frozen=True)
class DriverSensors:
    """What the motor's driver measures and how (see :mod:`.sensors`)."""

    current_range_a: float  # ADC full scale (+-)
    current_adc_bits: int
    current_noise_a: float  # white noise RMS at the ADC
    encoder_counts_per_motor_rev: float  # quadrature counts (x4) on the motor shaft
    speed_sources: tuple[str, ...]  # "position" (the tool differentiates) or "tacho"
    tacho_noise_rad_s: float = 0.0  # tachometer noise RMS at the measured shaft


@dataclass(frozen=True)
class BenchMotor:
    """One benchmark motor at its measured shaft, with its driver and test rates."""

    name: str
    params: MotorParams  # at the measured shaft
    voltage_rated_v: float
    current_rated_a: float
    gear_ratio: float  # 1 = direct drive
    power_rated_w: float
    rates_hz: tuple[float, ...]
    sensors: DriverSensors
    cogging_motor_periods: tuple[int, ...]  # per motor turn (slots x poles); () = ironless
    gear_teeth_output: int = 0  # output gear teeth (mesh ripple per output turn), 0 = direct

    @property
    def torque_rated_nm(self) -> float:
        return self.params.Kt * self.current_rated_a

    @property
    def speed_no_load_rad_s(self) -> float:
        return abs(self.params.steady_state(self.voltage_rated_v)[1])

    @property
    def counts_per_rev(self) -> float:
        return self.sensors.encoder_counts_per_motor_rev * self.gear_ratio

    @property
    def geared(self) -> bool:
        return self.gear_ratio > 1.0

    def inductance_visible(self, rate_hz: float) -> bool:
        """L/R spans at least two samples: only then can data show L changing."""
        return self.params.electrical_time_constant_s * rate_hz >= 2.0


def _motor(
    *,
    v_rated: float,
    i_stall: float,
    w0_motor: float,
    i0: float,
    inductance_h: float,
    j_rotor: float,
    j_load_out: float,
    gear: float,
) -> MotorParams:
    r = v_rated / i_stall
    ke_m = (v_rated - r * i0) / w0_motor
    b_m = 0.5 * ke_m * i0 / w0_motor
    ke = ke_m * gear
    return MotorParams(
        R=r,
        L=inductance_h,
        Ke=ke,
        Kt=ke,
        J=j_rotor * gear**2 + j_load_out,
        B=b_m * gear**2,
    )


def _rpm(x: float) -> float:
    return x * 2.0 * math.pi / 60.0


SOURCES: dict[str, str] = {
    "coreless_6v": "10 mm ironless (coreless) precision motor, 6 V, catalogue class",
    "gearmotor_12v": "micro metal gearmotor 12 V 'HP' class with a 100:1 spur gearbox",
    "servo_24v": "iron-core 24 V servo motor, 7 slots / 2 poles, with a flywheel load",
    "scooter_24v": "24 V 250 W e-scooter motor with 9.78:1 reduction and a wheel load",
    "industrial_180v": "1.5 hp 180 V PMDC industrial motor (SCR/PWM drive), coupled load",
    "traction_48v": "48 V 1.5 kW PMDC traction motor (golf cart / forklift class), vehicle load",
}

MOTORS: dict[str, BenchMotor] = {
    # 6 V, stall 0.3 A, 11,500 rpm no load at 12 mA, 0.1 g cm^2 rotor (+ 50 % for the
    # coupling), 0.15 mH: 0.45 W at most. Ironless: no cogging.
    "coreless_6v": BenchMotor(
        name="coreless_6v",
        params=_motor(
            v_rated=6.0,
            i_stall=0.3,
            w0_motor=_rpm(11500),
            i0=0.012,
            inductance_h=0.15e-3,
            j_rotor=1.0e-8,
            j_load_out=0.5e-8,
            gear=1.0,
        ),
        voltage_rated_v=6.0,
        current_rated_a=0.1,
        gear_ratio=1.0,
        power_rated_w=0.45,
        rates_hz=(2000.0, 5000.0, 10000.0),
        sensors=DriverSensors(0.5, 12, 1.0e-3, 64.0, ("position",)),
        cogging_motor_periods=(),
    ),
    # 12 V, stall 0.75 A, 31,000 rpm at 60 mA (motor), 100:1: 310 rpm out; rotor
    # 0.1 g cm^2 -> 1e-4 kg m^2 at the output, wheel 2e-5; 3 slots / 2 poles.
    "gearmotor_12v": BenchMotor(
        name="gearmotor_12v",
        params=_motor(
            v_rated=12.0,
            i_stall=0.75,
            w0_motor=_rpm(31000),
            i0=0.06,
            inductance_h=0.5e-3,
            j_rotor=1.0e-8,
            j_load_out=2.0e-5,
            gear=100.0,
        ),
        voltage_rated_v=12.0,
        current_rated_a=0.2,
        gear_ratio=100.0,
        power_rated_w=1.8,
        rates_hz=(250.0, 500.0, 1000.0),
        sensors=DriverSensors(2.5, 10, 8.0e-3, 48.0, ("position",)),
        cogging_motor_periods=(6,),
        gear_teeth_output=25,
    ),
    # 24 V, stall 40 A, 5,000 rpm at 0.25 A, rotor 250 g cm^2 + flywheel 500 g cm^2,
    # 0.9 mH; 4 A continuous (100 W); 7 slots / 2 poles: 14 cogging periods per turn.
    "servo_24v": BenchMotor(
        name="servo_24v",
        params=_motor(
            v_rated=24.0,
            i_stall=40.0,
            w0_motor=_rpm(5000),
            i0=0.25,
            inductance_h=0.9e-3,
            j_rotor=2.5e-5,
            j_load_out=5.0e-5,
            gear=1.0,
        ),
        voltage_rated_v=24.0,
        current_rated_a=4.0,
        gear_ratio=1.0,
        power_rated_w=100.0,
        rates_hz=(1000.0, 2000.0, 5000.0),
        sensors=DriverSensors(50.0, 12, 0.03, 2000.0, ("position", "tacho"), 0.5),
        cogging_motor_periods=(14,),
    ),
    # 24 V, stall 70 A, 3,000 rpm at 1.5 A (motor), 9.78:1: 307 rpm out; rotor
    # 3e-4 kg m^2 (x 95.6 at the output) + wheel 0.02; 0.6 mH; 13.4 A rated (250 W);
    # 3-phase-hall-like 13-line encoder on the motor; 12 slots / 4 poles.
    "scooter_24v": BenchMotor(
        name="scooter_24v",
        params=_motor(
            v_rated=24.0,
            i_stall=70.0,
            w0_motor=_rpm(3000),
            i0=1.5,
            inductance_h=0.6e-3,
            j_rotor=3.0e-4,
            j_load_out=0.02,
            gear=9.78,
        ),
        voltage_rated_v=24.0,
        current_rated_a=13.4,
        gear_ratio=9.78,
        power_rated_w=250.0,
        rates_hz=(250.0, 500.0, 1000.0, 2000.0),
        sensors=DriverSensors(100.0, 12, 0.08, 52.0, ("position",)),
        cogging_motor_periods=(12,),
        gear_teeth_output=17,
    ),
    # 180 V, 7 A, 1,750 rpm rated (1.5 hp = 1.1 kW); R 2.1 ohm, 28 mH, no-load 0.6 A
    # at 1,900 rpm; rotor 0.0065 kg m^2 + coupled load 0.01; 28 slots / 4 poles;
    # tachogenerator or 1024-line encoder.
    "industrial_180v": BenchMotor(
        name="industrial_180v",
        params=_motor(
            v_rated=180.0,
            i_stall=180.0 / 2.1,
            w0_motor=_rpm(1900),
            i0=0.6,
            inductance_h=28e-3,
            j_rotor=0.0065,
            j_load_out=0.01,
            gear=1.0,
        ),
        voltage_rated_v=180.0,
        current_rated_a=7.0,
        gear_ratio=1.0,
        power_rated_w=1100.0,
        rates_hz=(250.0, 500.0, 1000.0, 2000.0),
        sensors=DriverSensors(100.0, 12, 0.1, 4096.0, ("position", "tacho"), 0.3),
        cogging_motor_periods=(28,),
    ),
}

# Motors only the MuJoCo plant runs (``benchmark --plant mujoco``): the project's own
# generator keeps its five, so its draws (and the figures measured on them) stay.
MUJOCO_MOTORS: dict[str, BenchMotor] = {
    # 48 V, 0.06 ohm (stall 800 A), 3,300 rpm at 4 A no load, 150 uH; rotor 6e-3 kg m^2 +
    # the vehicle reflected to the shaft 0.015; 35 A continuous (1.5 kW at 3,000 rpm);
    # 24 cogging periods per turn; a 12-bit current sense over +-1000 A and a 64-line
    # encoder (256 counts), logged at 500 Hz to 2 kHz.
    "traction_48v": BenchMotor(
        name="traction_48v",
        params=_motor(
            v_rated=48.0,
            i_stall=800.0,
            w0_motor=_rpm(3300),
            i0=4.0,
            inductance_h=150e-6,
            j_rotor=6.0e-3,
            j_load_out=0.015,
            gear=1.0,
        ),
        voltage_rated_v=48.0,
        current_rated_a=35.0,
        gear_ratio=1.0,
        power_rated_w=1500.0,
        rates_hz=(500.0, 1000.0, 2000.0),
        sensors=DriverSensors(1000.0, 12, 0.5, 256.0, ("position", "tacho"), 0.3),
        cogging_motor_periods=(24,),
    ),
}
ALL_MOTORS: dict[str, BenchMotor] = {**MOTORS, **MUJOCO_MOTORS}
