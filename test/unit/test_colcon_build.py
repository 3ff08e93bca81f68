"""The package builds with colcon as a native ROS 2 install would build it, and the install is
complete: scripts where ``ros2 run`` looks, every subpackage, the data files the demo needs."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
COLCON = Path(sys.executable).parent / "colcon"
# one module of every subpackage: find_packages must have picked each of them up
MODULES = ("__init__.py", "core/board.py", "core/detect/__init__.py",
           "core/calibrate/session.py", "synth/dataset.py", "bag/reader.py", "ros/demo.py",
           "ros/processes.py", "cli/main.py")

pytestmark = pytest.mark.skipif(not COLCON.exists(),
                                reason="colcon is not installed in this environment")


@pytest.fixture(scope="module")
def install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``colcon build`` of a copy of the working tree's files; the package's install prefix."""
    ws = tmp_path_factory.mktemp("ws")
    src = ws / "src" / "artcal_ros"
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    for name in files:
        # bench/ and docs/ are not installed; of bags/ only the sample is
        if name.startswith(("bench/", "docs/")) or (name.startswith("bags/") and not
                                                    name.startswith("bags/sample/")):
            continue
        if not (ROOT / name).is_file():
            continue
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, src / name)
    env = dict(os.environ, PATH=f"{COLCON.parent}{os.pathsep}{os.environ.get('PATH', '')}")
    run = subprocess.run([str(COLCON), "build", "--base-paths", "src"], cwd=ws, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    return ws / "install" / "artcal_ros"


def _site_packages(prefix: Path) -> Path:
    (found,) = sorted(prefix.glob("lib/python*/site-packages"))
    return found


def test_colcon_build_installs_scripts_where_ros2_run_looks(install: Path) -> None:
    for exe in ("calibrator", "replay", "artcal"):
        assert (install / "lib" / "artcal_ros" / exe).is_file(), f"lib/artcal_ros/{exe} missing"
    index = install / "share" / "ament_index" / "resource_index" / "packages"
    assert (index / "artcal_ros").exists()
    assert (install / "share" / "artcal_ros" / "package.xml").exists()


def test_every_subpackage_is_installed(install: Path) -> None:
    package = _site_packages(install) / "artcal_ros"
    missing = [m for m in MODULES if not (package / m).is_file()]
    assert missing == [], f"not installed under {package}: {missing}"


def test_config_boards_and_sample_bag_are_installed_in_share(install: Path) -> None:
    share = install / "share" / "artcal_ros"
    assert (share / "config" / "calibrator.yaml").is_file()
    boards = sorted(p.name for p in (ROOT / "config" / "boards").glob("*.yaml"))
    assert boards, "config/boards has no board files"
    assert sorted(p.name for p in (share / "config" / "boards").glob("*.yaml")) == boards
    sample = sorted(p.name for p in (ROOT / "bags" / "sample").iterdir())
    assert {"metadata.yaml", "truth.json"} <= set(sample)
    assert sorted(p.name for p in (share / "bags" / "sample").iterdir()) == sample


def test_installed_demo_finds_its_bag_and_parameters(install: Path, tmp_path: Path) -> None:
    """Run from elsewhere, with no ament index to ask, the installed demo defaults to the
    installed sample bag and parameters file (found from where the package is installed)."""
    env = {k: v for k, v in os.environ.items() if k not in ("AMENT_PREFIX_PATH", "PYTHONPATH")}
    env["PYTHONPATH"] = str(_site_packages(install))  # ahead of the editable source tree
    code = ("import artcal_ros; from artcal_ros.ros import demo; print(artcal_ros.__file__); "
            "print(demo.data_file(demo.SAMPLE_BAG, '--bag')); "
            "print(demo.data_file(demo.PARAMS_FILE, '--params'))")
    run = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 0, run.stdout + run.stderr
    package, bag, params = (Path(line) for line in run.stdout.splitlines())
    assert package.is_relative_to(install), package
    share = install / "share" / "artcal_ros"
    assert (bag, params) == (share / "bags" / "sample", share / "config" / "calibrator.yaml")
