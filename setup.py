"""ament_python build of artcal_ros (colcon on native ROS 2, or pip into a venv).

Building also compiles the detector's numba kernels into the tree that will be imported (see
``artcal_ros/kernels.py``), so a user's first frame does not wait for the compiler.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup
from setuptools.command.build_py import build_py
from setuptools.command.develop import develop

PACKAGE = "artcal_ros"
HERE = Path(__file__).absolute().parent
# set to 1 to build without compiling the kernels (they then compile on first use)
SKIP_VARIABLE = "ARTCAL_NO_PRECOMPILE"
PRECOMPILE_TIMEOUT_S = 1800
# numba settings that would send the cache elsewhere or turn compiling off
NUMBA_OVERRIDES = ("NUMBA_CACHE_DIR", "NUMBA_DISABLE_JIT")


def _say(message: str, *, problem: bool = False) -> None:
    """One line of the build log (stderr for a problem, which colcon shows on the console)."""
    print(f"{PACKAGE}: {message}", file=sys.stderr if problem else sys.stdout, flush=True)


def _environments(tree: Path) -> list[dict[str, str]]:
    """Environments to compile in, in order of preference, each importing the package from
    ``tree``: the build's own, then this interpreter's own site-packages, which pip's build
    isolation hides (its PYTHONPATH and PYTHONNOUSERSITE) while the packages a user installed
    first (numba, numpy, OpenCV) are there."""
    base = {k: v for k, v in os.environ.items() if k not in NUMBA_OVERRIDES}
    inherited = [p for p in base.get("PYTHONPATH", "").split(os.pathsep) if p]
    build_env = dict(base, PYTHONPATH=os.pathsep.join([str(tree), *inherited]))
    own = {k: v for k, v in base.items() if k != "PYTHONNOUSERSITE"}
    own["PYTHONPATH"] = str(tree)
    return [build_env] if own == build_env else [build_env, own]


def precompile_kernels(tree: Path) -> None:
    """Compile and cache the kernels of the package under ``tree`` (the directory holding
    ``artcal_ros/``) in a fresh interpreter. Never fails the build: without numba, numpy or
    OpenCV, or on any error, it says so and the kernels compile on first use instead."""
    if os.environ.get(SKIP_VARIABLE, "") not in ("", "0"):
        _say(f"{SKIP_VARIABLE} is set: the kernels will compile on first use")
        return
    # cwd is the tree itself: `python -m` puts the working directory first on sys.path
    environments = _environments(tree)
    for env in environments:
        probe = subprocess.run([sys.executable, "-c", "import numba, numpy, cv2"], cwd=tree,
                               env=env, capture_output=True, text=True, check=False)
        if probe.returncode == 0:
            break
    else:
        _say(f"numba, numpy or OpenCV cannot be imported by {sys.executable}: the detector's "
             f"kernels will compile on first use (install them before {PACKAGE}, or run "
             f"`python -m {PACKAGE}.kernels` once after installing)", problem=True)
        return
    where = "" if env is environments[0] else f" (with {sys.executable}'s own packages)"
    _say(f"compiling the detector's kernels into {tree / PACKAGE}{where} (about half a minute)")
    start = time.monotonic()
    try:
        run = subprocess.run([sys.executable, "-m", f"{PACKAGE}.kernels"], cwd=tree, env=env,
                             capture_output=True, text=True, timeout=PRECOMPILE_TIMEOUT_S,
                             check=False)
    except subprocess.TimeoutExpired:
        _say(f"compiling the kernels took over {PRECOMPILE_TIMEOUT_S} s and was stopped: they "
             f"will compile on first use", problem=True)
        return
    if run.returncode != 0:
        _say(f"compiling the kernels failed after {time.monotonic() - start:.0f} s; they will "
             f"compile on first use:\n{run.stdout}{run.stderr[-4000:]}", problem=True)
        return
    print(run.stdout.strip(), flush=True)  # the module's own lines name the package


class BuildPyAndKernels(build_py):
    """``build_py``, then the kernels compiled into the built tree; in an editable install
    (``pip install -e``), into the source tree the install points at."""

    def run(self) -> None:
        """Copy the modules as usual, then compile the kernels next to them."""
        super().run()
        # setuptools before 64 (Ubuntu 22.04's) has no editable mode
        editable = getattr(self, "editable_mode", False)
        precompile_kernels(HERE if editable else Path(self.build_lib).absolute())


class DevelopAndKernels(develop):
    """``develop`` (``colcon build --symlink-install``), then the kernels compiled into the
    source tree it links to."""

    def run(self) -> None:
        """Link the package as usual, then compile the kernels in it."""
        super().run()
        if not self.uninstall:
            precompile_kernels(HERE)


setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["py.typed", "ros/fastdds_large_shm.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        # the Fast DDS profile the nodes apply to themselves, for a camera driver's use too
        (f"share/{PACKAGE}/config",
         [*glob("config/*.yaml"), f"{PACKAGE}/ros/fastdds_large_shm.xml"]),
        (f"share/{PACKAGE}/config/boards", glob("config/boards/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        # the sample recording and its truth: what the installed demo replays
        (f"share/{PACKAGE}/bags/sample", sorted(glob("bags/sample/*"))),
    ],
    python_requires=">=3.10",
    install_requires=["setuptools", "numpy", "opencv-python-headless", "numba", "mcap",
                      "mcap-ros2-support", "PyYAML", "matplotlib"],
    extras_require={"test": ["pytest", "hypothesis", "rosbags", "ruff", "mypy", "types-PyYAML"]},
    # numba caches its compiled kernels next to the sources: they must be files
    zip_safe=False,
    cmdclass={"build_py": BuildPyAndKernels, "develop": DevelopAndKernels},
    maintainer="artcal_ros maintainers",
    maintainer_email="maintainers@artcal.invalid",
    description="Automatic camera calibration from self-identifying marker boards",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            f"calibrator = {PACKAGE}.ros.calibrator:main",
            f"replay = {PACKAGE}.ros.replay:main",
            f"artcal = {PACKAGE}.cli.main:main",
        ],
    },
)
