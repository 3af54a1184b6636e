"""The identified motor in other tools' formats: MuJoCo MJCF, URDF, ros2_control, gains.

:func:`write_exports` writes them all beside a result (what the identification
node does with ``export_models:=true``); each format has its own module.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from pmdc_ident.core.motors import MotorSpec

__all__ = ["EXPORT_FILES", "write_exports"]

# what write_exports writes, by file name suffix after the stem
EXPORT_FILES: tuple[str, ...] = (".mjcf.xml", ".urdf", ".ros2_control.yaml", ".gains.yaml")


def write_exports(
    spec: MotorSpec,
    folder: str | Path,
    *,
    stem: str = "motor",
    reduction: float = 1.0,
    joint: str = "motor_joint",
    sample_rate_hz: float = 1000.0,
    speed_bandwidth_hz: float | None = None,
    phase_margin_deg: float = 60.0,
    diagnosis: Mapping[str, Any] | None = None,
) -> list[Path]:
    """MJCF, URDF, ros2_control parameters and checked gains of ``spec`` in ``folder``.

    ``speed_bandwidth_hz`` None takes a tenth of the current loop's crossover.
    ``diagnosis`` (the document ``pmdc-ident diagnose --json`` writes, or
    ``DiagnosisResult.to_json()``): the MJCF carries the diagnosis' model and every
    named effect MuJoCo can express (:func:`~pmdc_ident.exports.diagnosis.motor_with_diagnosis`);
    the other files keep ``spec``'s (URDF and the gains have no effect terms).
    Returns the paths written. Raises a :class:`~pmdc_ident.core.errors.PmdcError`
    subclass when the gains cannot be designed for these settings.
    """
    import yaml

    from pmdc_ident.core.control_design import check_gains, current_crossover_hz, design_gains
    from pmdc_ident.core.safe_write import write_text
    from pmdc_ident.exports.mujoco_xml import mujoco_xml
    from pmdc_ident.exports.urdf import ros2_control_yaml, urdf_xml

    out = Path(folder)
    paths = [out / f"{stem}{suffix}" for suffix in EXPORT_FILES]
    bandwidth = speed_bandwidth_hz or current_crossover_hz(sample_rate_hz, phase_margin_deg) / 10
    design = design_gains(
        spec.model.params,
        spec.limits,
        sample_rate_hz=sample_rate_hz,
        speed_bandwidth_hz=bandwidth,
        phase_margin_deg=phase_margin_deg,
    )
    mjcf_spec = spec
    if diagnosis is not None:
        from pmdc_ident.exports.diagnosis import motor_with_diagnosis

        mjcf_spec = motor_with_diagnosis(spec, diagnosis).spec
    mujoco_xml(mjcf_spec, reduction=reduction, joint=joint).write(paths[0])
    write_text(paths[1], urdf_xml(spec, reduction=reduction, joint=joint))
    write_text(paths[2], ros2_control_yaml(spec, design, reduction=reduction, joint=joint))
    data = design.as_dict()
    data["verification"] = [
        {
            "plant": c.plant,
            "overshoot_pct": c.measured.overshoot_pct,
            "settling_2pct_s": c.measured.settling_s,
            "within_promise": c.ok,
        }
        for c in check_gains(design, spec)
    ]
    write_text(paths[3], yaml.safe_dump(data, sort_keys=False))
    return paths
