"""The core stays ROS-free; the package metadata agrees with itself."""

from __future__ import annotations

import ast
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

ROS_MODULES = {"rclpy", "sensor_msgs", "std_srvs", "diagnostic_msgs", "std_msgs",
               "builtin_interfaces", "rosidl_runtime_py"}


def _imported_roots(path) -> set[str]:
    tree = ast.parse(path.read_text(), filename=str(path))
    roots: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            roots.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            roots.add(node.module.split(".")[0])
    return roots


def test_core_imports_no_ros() -> None:
    files = sorted((ROOT / "artcal_ros" / "core").glob("*.py"))
    assert files, "artcal_ros/core has no modules"
    offenders = {f.name: sorted(_imported_roots(f) & ROS_MODULES) for f in files}
    assert {k: v for k, v in offenders.items() if v} == {}


def test_bag_module_imports_no_rclpy() -> None:
    bag = ROOT / "artcal_ros" / "bag.py"
    if bag.exists():
        assert "rclpy" not in _imported_roots(bag)


def test_package_xml_is_ament_python_format_3() -> None:
    root = ET.parse(ROOT / "package.xml").getroot()
    assert root.get("format") == "3"
    assert root.findtext("name") == "artcal_ros"
    assert root.findtext("export/build_type") == "ament_python"
    deps = {e.text for e in root.findall("exec_depend")}
    assert {"rclpy", "sensor_msgs", "std_srvs", "diagnostic_msgs"} <= deps
    setup_cfg = (ROOT / "setup.cfg").read_text()
    assert "script_dir=$base/lib/artcal_ros" in setup_cfg
    assert "install_scripts=$base/lib/artcal_ros" in setup_cfg
    assert (ROOT / "resource" / "artcal_ros").exists()
    assert (ROOT / "artcal_ros" / "py.typed").exists()
