"""The package builds with colcon as a native ROS 2 install would build it, and the install is
complete: scripts where ``ros2 run`` looks, every subpackage, the data files the demo needs, and
the detector's kernels compiled, so that a fresh process's first detection compiles nothing
(the same for ``--symlink-install`` and for pip's editable install, which ``make`` uses)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
COLCON = Path(sys.executable).parent / "colcon"
# one module of every subpackage: find_packages must have picked each of them up
MODULES = ("__init__.py", "core/board/board.py", "core/detect/__init__.py",
           "core/calibrate/solve_run.py", "core/images/raw.py", "core/live/stream.py",
           "synth/dataset.py", "bag/reader.py", "ros/demo.py", "ros/processes.py", "cli/main.py")

# a cold build compiles the kernels (half a minute on an idle 2-core machine, more when busy)
BUILD_TIMEOUT_S = 900
# A fresh process renders a frame, then times its first detect() and names the kernels it
# compiled instead of loading them from the cache.
FIRST_DETECT = """
import json, time
import numpy as np
import artcal_ros
from artcal_ros.core.board import Board
from artcal_ros.core.detect import detect
from artcal_ros.kernels import compiled_here
from artcal_ros.synth import Camera, Photometry, random_poses, render_view
board, cam, rng = Board(), Camera.preset("webcam"), np.random.default_rng(7)
((rvec, tvec),) = random_poses(board, cam, 1, rng)
view = render_view(board, cam, rvec, tvec, rng=rng, photometry=Photometry.clean())
start = time.monotonic()
markers = detect(view.image, board)
print(json.dumps({"file": artcal_ros.__file__, "first_detect_s": time.monotonic() - start,
                  "markers": len(markers), "compiled": compiled_here()}))
"""

pytestmark = pytest.mark.skipif(not COLCON.exists(),
                                reason="colcon is not installed in this environment")


@pytest.fixture(scope="module")
def workspace(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A colcon workspace whose ``src/artcal_ros`` is a copy of the working tree's files (no
    ``__pycache__``: the kernels start uncompiled)."""
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
    return ws


def _colcon_build(ws: Path, *options: str) -> None:
    """``colcon build`` of the workspace with extra options; fails the test if it fails."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env["PATH"] = f"{COLCON.parent}{os.pathsep}{os.environ.get('PATH', '')}"
    run = subprocess.run([str(COLCON), "build", "--base-paths", "src", *options], cwd=ws,
                         env=env, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    assert run.returncode == 0, run.stdout + run.stderr


@pytest.fixture(scope="module")
def install(workspace: Path) -> Path:
    """``colcon build`` of the workspace; the package's install prefix."""
    _colcon_build(workspace)
    return workspace / "install" / "artcal_ros"


def _cache_files(root: Path) -> dict[Path, tuple[int, int]]:
    """numba's cache files under ``root``: index (.nbi) and code (.nbc), with mtime and size."""
    return {p: (p.stat().st_mtime_ns, p.stat().st_size)
            for p in sorted(root.rglob("__pycache__/*.nb[ic]"))}


def _first_detect(pythonpath: Path, cwd: Path) -> dict:
    """Run FIRST_DETECT in a fresh interpreter importing the package from ``pythonpath``
    (the source tree is not on the path: cwd is elsewhere and no editable finder is reached)
    and check that it compiled nothing and wrote no cache file; its report."""
    env = {k: v for k, v in os.environ.items()
           if k not in ("AMENT_PREFIX_PATH", "PYTHONPATH") and not k.startswith("NUMBA_")}
    env["PYTHONPATH"] = str(pythonpath)
    package = pythonpath / "artcal_ros"
    before = _cache_files(package)
    assert before, f"no compiled kernels under {package}"
    run = subprocess.run([sys.executable, "-c", FIRST_DETECT], cwd=cwd, env=env,
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    report = json.loads(run.stdout.splitlines()[-1])
    assert Path(report["file"]).is_relative_to(pythonpath), report["file"]
    assert report["markers"] > 20, report
    assert report["compiled"] == {}, f"compiled at run time: {report['compiled']}"
    assert _cache_files(package) == before, "the first detection wrote to the kernel cache"
    return report


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
    # the nodes' Fast DDS profile, for a camera driver too, and the copy the nodes read
    assert (share / "config" / "fastdds_large_shm.xml").is_file()
    assert (_site_packages(install) / "artcal_ros" / "ros" / "fastdds_large_shm.xml").is_file()
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


def test_first_detection_in_the_colcon_install_compiles_nothing(install: Path,
                                                                 tmp_path: Path) -> None:
    report = _first_detect(_site_packages(install), tmp_path)
    print(f"first detect() in the colcon install: {report['first_detect_s']:.2f} s "
          f"({report['markers']} markers)")


def test_compiled_kernels_survive_a_copy_that_renews_file_times(install: Path,
                                                                tmp_path: Path) -> None:
    """pip installing a wheel writes the files anew (new mtimes); numba stamps its cache by the
    source's content, so the built cache still serves a copy made that way."""
    site = tmp_path / "site-packages"
    shutil.copytree(_site_packages(install) / "artcal_ros", site / "artcal_ros",
                    copy_function=shutil.copy)  # copies content, not times
    source = site / "artcal_ros" / "core" / "detect" / "sides.py"
    built = _site_packages(install) / "artcal_ros" / "core" / "detect" / "sides.py"
    assert source.stat().st_mtime_ns != built.stat().st_mtime_ns
    report = _first_detect(site, tmp_path)
    print(f"first detect() in a copy with new file times: {report['first_detect_s']:.2f} s")


def test_first_detection_after_symlink_install_compiles_nothing(workspace: Path,
                                                                tmp_path: Path) -> None:
    """``colcon build --symlink-install`` (``setup.py develop``): the build directory links to
    the sources, whose ``__pycache__`` gets the kernels."""
    _colcon_build(workspace, "--symlink-install", "--build-base", "build_symlink",
                  "--install-base", "install_symlink")
    report = _first_detect(workspace / "build_symlink" / "artcal_ros", tmp_path)
    print(f"first detect() after --symlink-install: {report['first_detect_s']:.2f} s")


def test_editable_install_compiles_the_kernels_in_the_source_tree(workspace: Path,
                                                                  tmp_path: Path) -> None:
    """What ``make`` runs (``pip install --no-build-isolation -e .``) is setuptools' editable
    build in the current environment; called here directly, so the shared .venv's own editable
    install is left alone. Its log names the source tree, and a process importing the package
    from there compiles nothing."""
    src = workspace / "src" / "artcal_ros"
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    build = ("from setuptools import build_meta; import sys; "
             "build_meta.build_editable(sys.argv[1])")
    (tmp_path / "wheel").mkdir()
    run = subprocess.run([sys.executable, "-c", build, str(tmp_path / "wheel")], cwd=src,
                         env=env, capture_output=True, text=True, timeout=BUILD_TIMEOUT_S)
    assert run.returncode == 0, run.stdout + run.stderr
    assert f"compiling the detector's kernels into {src / 'artcal_ros'}" in run.stdout, (
        run.stdout + run.stderr)
    report = _first_detect(src, tmp_path)
    print(f"first detect() in the editable source tree: {report['first_detect_s']:.2f} s")
