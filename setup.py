"""ament_python build of artcal_ros (colcon on native ROS 2, or pip into a venv)."""

from glob import glob

from setuptools import find_packages, setup

PACKAGE = "artcal_ros"

setup(
    name=PACKAGE,
    version="0.1.0",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*"]),
    package_data={PACKAGE: ["py.typed", "ros/fastdds_large_shm.xml"]},
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (f"share/{PACKAGE}", ["package.xml"]),
        (f"share/{PACKAGE}/config", glob("config/*.yaml")),
        (f"share/{PACKAGE}/config/boards", glob("config/boards/*.yaml")),
        (f"share/{PACKAGE}/launch", glob("launch/*.launch.py")),
        # the sample recording and its truth: what the installed demo replays
        (f"share/{PACKAGE}/bags/sample", sorted(glob("bags/sample/*"))),
    ],
    python_requires=">=3.10",
    install_requires=["setuptools", "numpy", "opencv-python-headless", "numba", "mcap",
                      "mcap-ros2-support", "PyYAML"],
    extras_require={"test": ["pytest", "hypothesis", "rosbags", "ruff", "mypy", "types-PyYAML"]},
    # numba caches its compiled kernels next to the sources: they must be files
    zip_safe=False,
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
