import os

from setuptools import find_packages, setup

package_name = "pmdc_ident"


def _tree(src: str) -> list[tuple[str, list[str]]]:
    """data_files entries installing ``src/`` under share/<pkg>/, keeping subfolders.

    Dot-files (such as launch/.gitkeep) and __pycache__ are left out.
    """
    entries = []
    for folder, dirs, files in os.walk(src):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d != "__pycache__")
        paths = sorted(os.path.join(folder, f) for f in files if not f.startswith("."))
        entries.append((os.path.join("share", package_name, folder), paths))
    return entries


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        *_tree("config"),
        *_tree("launch"),
        *_tree("firmware"),  # virtual-board --emulated builds the sketch from here
    ],
    # Only the numerics. ROS (rclpy, message packages) comes from the ROS
    # distribution on a robot, or from requirements-dev.txt in the .venv.
    install_requires=["numpy", "scipy", "pyyaml"],
    # `pmdc-ident` is a launcher of its own (scripts/pmdc-ident: python -S, so a Ctrl-C
    # during the interpreter's start-up is held, never a traceback); the nodes below are
    # generated wrappers
    scripts=["scripts/pmdc-ident"],
    zip_safe=True,
    maintainer="pmdc_ident developers",
    maintainer_email="pmdc_ident@example.com",
    description="Identify brushed PMDC motor parameters and diagnose the sim-to-real gap.",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "driver_node = pmdc_ident.nodes.driver_node:main",
            "identification_node = pmdc_ident.nodes.identification_node:main",
            "recorder_node = pmdc_ident.nodes.recorder_node:main",
            "bringup = pmdc_ident.process.bringup:main",
            "monitor_node = pmdc_ident.nodes.monitor_node:main",
        ],
    },
)
