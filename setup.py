import os
from glob import glob

from setuptools import find_packages, setup

package_name = "pmdc_ident"


def _files(pattern: str) -> list[str]:
    """Regular files matching ``pattern`` (skips directories and dot-files)."""
    return sorted(p for p in glob(pattern) if os.path.isfile(p))


setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test", "test.*"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", _files("config/*")),
        ("share/" + package_name + "/launch", _files("launch/*")),
    ],
    # Only the numerics. ROS (rclpy, message packages) comes from the ROS
    # distribution on a robot, or from requirements-dev.txt in the .venv.
    install_requires=["numpy", "scipy", "pyyaml"],
    zip_safe=True,
    maintainer="pmdc_ident developers",
    maintainer_email="pmdc_ident@example.com",
    description="Identify brushed PMDC motor parameters and diagnose the sim-to-real gap.",
    license="Apache-2.0",
    python_requires=">=3.10",
    entry_points={
        "console_scripts": [
            "pmdc-ident = pmdc_ident.cli:main",
            "driver_node = pmdc_ident.nodes.driver_node:main",
            "identification_node = pmdc_ident.nodes.identification_node:main",
            "recorder_node = pmdc_ident.nodes.recorder_node:main",
            "bringup = pmdc_ident.nodes.bringup:main",
        ],
    },
)
