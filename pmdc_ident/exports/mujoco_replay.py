"""Replay recorded voltages in an exported MuJoCo model (``pmdc-ident roundtrip``).

Each segment is replayed from its own initial state, as the project's model predicts a
held-out segment: the current, speed and angle its first samples show, the winding's
temperature from the heat the record put in before it, the commands before it in
MuJoCo's ctrl history (for the actuator's delay). The voltage is held over each
sample; an open armature (NaN) sets the motor's constant to 0 and its current to 0, as
:mod:`pmdc_ident.benchmark.mujoco_plant` does. ``mujoco`` is imported here only, when
a replay runs.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment

__all__ = ["Replayed", "SegmentStart", "mujoco_warnings_caught", "replay_segments"]

FloatArray = NDArray[np.float64]


@contextmanager
def mujoco_warnings_caught() -> Iterator[list[str]]:
    """MuJoCo's warnings (an unstable step, ...) collected into the yielded list instead
    of printed and appended to a MUJOCO_LOG.TXT in the working folder; the previous
    handler is restored after."""
    import mujoco

    caught: list[str] = []
    previous = mujoco.get_mju_user_warning()
    mujoco.set_mju_user_warning(caught.append)
    try:
        yield caught
    finally:
        mujoco.set_mju_user_warning(previous)


@dataclass(frozen=True)
class SegmentStart:
    """A segment's state at its first sample, at the motor shaft, in real units."""

    current_a: float
    speed_rad_s: float
    angle_rad: float
    temperature_k: float = 0.0  # the winding's rise above ambient (MuJoCo's thermal state)


@dataclass(frozen=True)
class Replayed:
    """MuJoCo's free run of one segment (the fields of a prediction)."""

    label: str
    t: FloatArray
    current: FloatArray
    speed: FloatArray
    position: FloatArray


def replay_segments(
    xml: str,
    segments: Sequence[Segment],
    starts: Sequence[SegmentStart],
    *,
    reduction: float = 1.0,
    current_scale: float = 1.0,
) -> list[Replayed]:
    """Free runs of ``segments`` in the MJCF ``xml`` (its first actuator the motor, its
    timestep a whole fraction of the segments' sample period), each from its start.
    ``current_scale``: MuJoCo's current per real ampere (Kt/Ke of the export)."""
    import mujoco

    with mujoco_warnings_caught() as caught:
        out = _replay(mujoco, xml, segments, starts, reduction, current_scale)
    if caught:
        msg = f"MuJoCo's replay went unstable: {caught[0].strip()}"
        raise ValueError(msg)
    return out


def _replay(mujoco, xml, segments, starts, reduction, current_scale) -> list[Replayed]:  # type: ignore[no-untyped-def]
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    h = float(model.opt.timestep)
    adr0, nact = int(model.actuator_actadr[0]), int(model.actuator_actnum[0])
    cur = adr0 + nact - 1
    dyn = model.actuator_dynprm[0]
    temp = adr0 if dyn[2] > 0 else -1  # slots: temperature, bristle, current
    k_motor = float(model.actuator_gainprm[0, 1])
    # the actuator that takes the command: the motor, or a drive in front of it (a lag)
    inp = next((a for a in range(model.actuator_ctrlnum.size) if model.actuator_ctrlnum[a] > 0), 0)
    nsample = int(model.actuator_history[inp, 0]) if model.actuator_history.size else 0
    delay_s = float(model.actuator_delay[inp])
    lag_dof, lag_s = _drive_lag(mujoco, model, inp)
    out = []
    for seg, x0 in zip(segments, starts, strict=True):
        nsub = int(round(seg.dt_s / h))
        if nsub < 1 or abs(nsub * h - seg.dt_s) > 1e-6 * seg.dt_s:
            msg = f"MuJoCo step {h:g} s is no whole fraction of the sample period {seg.dt_s:g} s"
            raise ValueError(msg)
        mujoco.mj_resetData(model, data)
        data.qpos[0] = x0.angle_rad / reduction
        data.qvel[0] = x0.speed_rad_s / reduction
        data.act[cur] = x0.current_a * current_scale
        if temp >= 0:
            data.act[temp] = x0.temperature_k
        for adr, z in _bristle_states(model, x0.speed_rad_s / reduction):
            data.act[adr] = z
        if nsample > 0 and seg.history_voltage is not None and seg.history_voltage.size:
            _init_history(model, data, seg, nsample, inp)
        v = seg.voltage if seg.voltage is not None else np.zeros(seg.n)
        if lag_dof >= 0:
            data.qvel[lag_dof] = _lag_state(v, seg.history_voltage, delay_s, lag_s, seg.dt_s)
        n = seg.n
        opened = _open_mask(v, seg.history_voltage, delay_s, seg.dt_s)
        i_out, w_out, th_out = np.empty(n), np.empty(n), np.empty(n)
        was_open = False
        for k in range(n):
            i_out[k] = data.act[cur] / current_scale
            w_out[k] = data.qvel[0] * reduction
            th_out[k] = data.qpos[0] * reduction
            is_open = bool(opened[k])
            if is_open != was_open:
                was_open = is_open
                model.actuator_gainprm[0, 1] = 0.0 if is_open else k_motor
            if is_open:
                data.act[cur] = 0.0
                data.ctrl[0] = 0.0
                for _ in range(nsub):
                    mujoco.mj_step(model, data)
                    data.act[cur] = 0.0
                    if lag_dof >= 0:  # the drive's lag restarts from 0 V after an open interval
                        data.qvel[lag_dof] = 0.0
            else:
                data.ctrl[0] = 0.0 if math.isnan(v[k]) else v[k]
                mujoco.mj_step(model, data, nsub)
        model.actuator_gainprm[0, 1] = k_motor
        if not (np.isfinite(i_out).all() and np.isfinite(w_out).all()):
            msg = f"MuJoCo's replay of {seg.label} went unstable"
            raise ValueError(msg)
        out.append(Replayed(seg.label, seg.t.copy(), i_out, w_out, th_out))
    return out


def _open_mask(v: FloatArray, history: FloatArray | None, delay_s: float, dt_s: float):  # type: ignore[no-untyped-def]
    """Where the armature is open: where the command is NaN, as late as the actuator's
    delay (the drive's open command travels the same path; the project's model delays it
    by the rounded number of samples)."""
    shift = int(math.floor(delay_s / dt_s + 0.5)) if delay_s > 0 else 0
    if shift == 0:
        return np.isnan(v)
    before = np.zeros(shift)
    if history is not None and history.size:
        h = np.asarray(history, dtype=float)[-shift:]
        before[shift - h.size :] = np.isnan(h)
    return np.concatenate([before.astype(bool), np.isnan(v)])[: v.size]


def _bristle_states(model, speed: float) -> list[tuple[int, float]]:  # type: ignore[no-untyped-def]
    """Every LuGre element's bristles at their steady deflection for the start's speed
    (``speed`` at the joint; 0 at rest): (activation address, deflection) pairs."""
    out = []
    for a in range(model.actuator_dynprm.shape[0]):
        dyn = model.actuator_dynprm[a]
        sig0 = float(dyn[5])
        if sig0 <= 0 or int(model.actuator_actnum[a]) < 1:
            continue
        adr = int(model.actuator_actadr[a]) + (1 if dyn[2] > 0 else 0)  # after a temperature
        fc, fs, vs = (float(x) for x in model.actuator_biasprm[a, 3:6])
        w = speed * float(model.actuator_gear[a, 0])  # the element's own shaft
        z = 0.0
        if w != 0.0:
            g = fc + (fs - fc) * math.exp(-((w / max(vs, 1e-12)) ** 2))
            z = math.copysign(g / sig0, w)
        out.append((adr, z))
    return out


def _drive_lag(mujoco, model, inp: int) -> tuple[int, float]:  # type: ignore[no-untyped-def]
    """A drive's first-order lag in front of the motor (:func:`~pmdc_ident.exports.
    mujoco_xml.mujoco_xml`): the drive joint's dof and time constant, or (-1, 0)."""
    if inp == 0 or int(model.actuator_trntype[inp]) != int(mujoco.mjtTrn.mjTRN_JOINT):
        return -1, 0.0
    dof = int(model.jnt_dofadr[int(model.actuator_trnid[inp, 0])])
    damping = float(model.dof_damping[dof])
    if not damping > 0:
        return -1, 0.0
    return dof, float(model.dof_armature[dof]) / damping


def _lag_state(v: FloatArray, history: FloatArray | None, delay_s: float, lag_s: float,
               dt_s: float) -> float:  # fmt: skip
    """The lagged voltage at a segment's start, as the project's model has it: the
    (delayed) commands before it through the lag from the oldest one held; without
    them, the first command."""
    from pmdc_ident.core.model import apply_delay, lagged

    first = float(v[0]) if v.size and math.isfinite(v[0]) else 0.0
    if history is None or not np.asarray(history).size or not lag_s > 0:
        return first
    pre = np.asarray(history, dtype=float)
    both = apply_delay(np.concatenate([pre, v]), delay_s, dt_s, float(pre[0]))[: pre.size]
    x0 = float(pre[0]) if math.isfinite(pre[0]) else 0.0
    return lagged(both, lag_s, dt_s, x0)[1]


def _init_history(model, data, seg: Segment, nsample: int, inp: int = 0) -> None:  # type: ignore[no-untyped-def]
    """MuJoCo's ctrl history: the commands before the segment at the buffer's times."""
    import mujoco

    hist = np.asarray(seg.history_voltage, dtype=float)
    h = float(model.opt.timestep)
    times = -h * np.arange(nsample, 0, -1, dtype=float)  # [..., -2h, -h], as after a reset
    idx = np.floor(times / seg.dt_s + 1e-9).astype(int)  # -1: the sample just before
    vals = np.array([hist[k] if -k <= hist.size else hist[0] for k in idx], dtype=float)
    vals = np.where(np.isnan(vals), 0.0, vals)
    mujoco.mj_initCtrlHistory(model, data, inp, times.reshape(-1, 1), vals.reshape(-1, 1))
