"""The package builds with colcon as a native ROS 2 install would build it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
COLCON = Path(sys.executable).parent / "colcon"


@pytest.mark.skipif(not COLCON.exists(), reason="colcon is not installed in this environment")
def test_colcon_build_installs_scripts_where_ros2_run_looks(tmp_path: Path) -> None:
    src = tmp_path / "src" / "artcal_ros"
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()
    for name in files:
        if name.startswith(("bags/", "bench/", "docs/")) or not (ROOT / name).is_file():
            continue
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(ROOT / name, src / name)
    env = dict(os.environ, PATH=f"{COLCON.parent}{os.pathsep}{os.environ.get('PATH', '')}")
    run = subprocess.run([str(COLCON), "build", "--base-paths", "src"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    prefix = tmp_path / "install" / "artcal_ros"
    for exe in ("calibrator", "replay", "artcal"):
        assert (prefix / "lib" / "artcal_ros" / exe).is_file(), f"lib/artcal_ros/{exe} missing"
    index = prefix / "share" / "ament_index" / "resource_index" / "packages"
    assert (index / "artcal_ros").exists()
    assert (prefix / "share" / "artcal_ros" / "package.xml").exists()
    assert (prefix / "share" / "artcal_ros" / "config" / "calibrator.yaml").exists()
