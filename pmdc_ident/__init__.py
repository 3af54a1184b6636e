"""pmdc_ident: identify brushed permanent-magnet DC motor parameters.

The ROS-free layers (core, io, backends, cli) never import rclpy or message
packages; only ``pmdc_ident.nodes`` does.

The names below are importable from the package itself (``from pmdc_ident import
mujoco_xml``); each is loaded on first use, so ``import pmdc_ident`` stays cheap.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

# public name -> module that defines it
_LAZY: dict[str, str] = {
    "load_motor": "pmdc_ident.core.motors",
    "MotorSpec": "pmdc_ident.core.motors",
    "MotorParams": "pmdc_ident.core.params",
    "Model": "pmdc_ident.core.model",
    "design_gains": "pmdc_ident.core.control_design",
    "check_gains": "pmdc_ident.core.control_design",
    "verify_gains": "pmdc_ident.core.control_design",
    "GainDesign": "pmdc_ident.core.control_design",
    "mujoco_xml": "pmdc_ident.exports.mujoco_xml",
    "urdf_xml": "pmdc_ident.exports.urdf",
    "ros2_control_yaml": "pmdc_ident.exports.urdf",
    "write_exports": "pmdc_ident.exports",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        msg = f"module 'pmdc_ident' has no attribute {name!r}"
        raise AttributeError(msg)
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value
