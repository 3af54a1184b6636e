"""`colcon build` of the package gives the install tree `ros2 run`/`ros2 launch` expect.

The repository's package files are copied into a throw-away workspace
(`src/pmdc_ident`) and built with the colcon in this interpreter's environment
(colcon-core + colcon-ros + colcon-python-setup-py from requirements-dev.txt).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.paths import REPO

pytestmark = pytest.mark.slow

PACKAGE_CONTENT = (
    "package.xml",
    "setup.py",
    "setup.cfg",
    "resource",
    "pmdc_ident",
    "config",
    "scripts",
)
OPTIONAL_CONTENT = ("launch",)
CONSOLE_SCRIPTS = (
    "pmdc-ident",
    "driver_node",
    "identification_node",
    "recorder_node",
    "bringup",
    "monitor_node",
)


def _data_files(folder: str) -> list[Path]:
    """Files under REPO/folder that setup.py installs (no dot-files, no caches)."""
    root = REPO / folder
    if not root.is_dir():
        return []
    return sorted(
        p.relative_to(root)
        for p in root.rglob("*")
        if p.is_file()
        and not any(part.startswith(".") or part == "__pycache__" for part in p.parts)
    )


@pytest.fixture(scope="module")
def install_prefix(tmp_path_factory) -> Path:
    ws = tmp_path_factory.mktemp("colcon_ws")
    src = ws / "src" / "pmdc_ident"
    src.mkdir(parents=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info")
    for name in PACKAGE_CONTENT + OPTIONAL_CONTENT:
        origin = REPO / name
        if origin.is_dir():
            shutil.copytree(origin, src / name, ignore=ignore)
        elif origin.is_file():
            shutil.copy2(origin, src / name)
        else:
            assert name in OPTIONAL_CONTENT, f"{name} is missing from the repository"

    colcon = Path(sys.executable).parent / "colcon"
    assert colcon.is_file(), f"colcon not installed next to {sys.executable}"
    env = {
        k: v
        for k, v in os.environ.items()
        if not k.startswith(("COLCON_", "AMENT_", "CMAKE_PREFIX_PATH"))
    }
    env["COLCON_HOME"] = str(ws / "colcon_home")  # no user-level defaults.yaml
    result = subprocess.run(
        [
            str(colcon),
            "--log-base",
            str(ws / "log"),
            "build",
            "--base-paths",
            str(ws / "src"),
            "--build-base",
            str(ws / "build"),
            "--install-base",
            str(ws / "install"),
            "--event-handlers",
            "console_direct+",
        ],
        cwd=ws,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert result.returncode == 0, f"colcon build failed:\n{result.stdout}\n{result.stderr}"
    assert "Finished <<< pmdc_ident" in result.stdout + result.stderr
    return ws / "install" / "pmdc_ident"


@pytest.mark.parametrize("script", CONSOLE_SCRIPTS)
def test_console_script_is_installed_where_ros2_run_looks(install_prefix, script):
    path = install_prefix / "lib" / "pmdc_ident" / script
    assert path.is_file(), f"{path} missing"
    assert os.access(path, os.X_OK), f"{path} is not executable"
    assert path.read_text().startswith("#!"), f"{path} has no interpreter line"


def test_package_xml_is_installed(install_prefix):
    installed = install_prefix / "share" / "pmdc_ident" / "package.xml"
    assert installed.read_bytes() == (REPO / "package.xml").read_bytes()


def test_ament_index_marker_is_installed(install_prefix):
    marker = install_prefix / "share" / "ament_index" / "resource_index" / "packages"
    assert (marker / "pmdc_ident").is_file()
    # Built as ament_python (colcon-ros), which adds the AMENT_PREFIX_PATH hook.
    assert (install_prefix / "share" / "pmdc_ident" / "hook" / "ament_prefix_path.dsv").is_file()


def test_config_files_are_installed(install_prefix):
    expected = _data_files("config")
    assert Path("fastdds_localhost.xml") in expected
    share = install_prefix / "share" / "pmdc_ident" / "config"
    missing = [str(p) for p in expected if not (share / p).is_file()]
    assert missing == []


def test_launch_files_are_installed(install_prefix):
    share = install_prefix / "share" / "pmdc_ident" / "launch"
    assert share.is_dir()
    missing = [str(p) for p in _data_files("launch") if not (share / p).is_file()]
    assert missing == []


def test_installed_python_package_is_the_one_imported(install_prefix):
    site = next((install_prefix / "lib").glob("python3*/site-packages"))
    result = subprocess.run(
        [
            sys.executable,
            "-c",
            "import pmdc_ident; print(pmdc_ident.__file__, pmdc_ident.__version__)",
        ],
        env={**os.environ, "PYTHONPATH": str(site)},
        cwd=install_prefix,
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stderr
    file_name, version = result.stdout.split()
    assert Path(file_name).is_relative_to(site)
    assert version == "0.1.0"
