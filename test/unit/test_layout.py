"""The package's layout rules (docs/architecture.md, "What may import what") hold; the package
metadata agrees with itself.

- core/, synth/ and bag/ are ROS-free: no module in them (at any depth, in any function)
  imports rclpy or a ROS message package, and importing all of them loads none.
- Imports run downward: core uses none of synth, bag, ros, cli; synth and bag use neither ros
  nor cli; bag does not use synth; cli does not use ros, nor ros cli.
- No import cycle anywhere in artcal_ros, and every import of artcal_ros names a module that
  exists.
- No module is over MAX_LINES lines.
- Inside core/detect/ the imports follow the layers its ``__init__`` docstring states: every
  module in exactly one layer, and each imports only modules of later (lower) layers.

Imports are read with :mod:`ast`, so every import counts: module level, inside functions and
methods, relative, ``from package import submodule``, and ``importlib.import_module`` with a
literal name (an f-string with a literal ``artcal_ros.x.`` prefix counts as importing every
module under that prefix).
"""

from __future__ import annotations

import ast
import itertools
import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE_DIR = ROOT / "artcal_ros"
ROS_FREE = ("core", "synth", "bag")
MAX_LINES = 500
# What each top-level subpackage may not import (DESIGN.md: "cli and ros use core, synth and
# bag; core uses none of them"). ros and cli are siblings at the top: neither uses the other.
FORBIDDEN = {
    "core": {"synth", "bag", "ros", "cli"},
    "synth": {"ros", "cli"},
    "bag": {"ros", "cli", "synth"},
    "cli": {"ros"},
    "ros": {"cli"},
}
ROS_MODULES = {"rclpy", "std_srvs", "builtin_interfaces", "ament_index_python", "launch",
               "launch_ros", "cv_bridge", "message_filters", "image_transport",
               "camera_info_manager", "tf2_ros"}


def is_ros_module(name: str) -> bool:
    """True for a ROS 2 Python module (rclpy, message and service packages, rosidl, ament)."""
    root = name.split(".")[0]
    return (root in ROS_MODULES or root.startswith(("rclpy", "rcl_", "rosidl_", "rosbag2",
                                                    "ros2", "ament_"))
            or root.endswith(("_msgs", "_srvs", "_interfaces")))


@dataclass(frozen=True)
class Import:
    """One import of a module: the target module's dotted name and where it is written."""

    target: str
    line: int
    implicit: bool = False  # a parent package that importing ``target`` initialises


def module_name(path: Path) -> str:
    """``artcal_ros/core/detect/__init__.py`` -> ``artcal_ros.core.detect``."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def package_modules() -> dict[str, Path]:
    """Every module of artcal_ros by dotted name."""
    files = sorted(p for p in PACKAGE_DIR.rglob("*.py") if "__pycache__" not in p.parts)
    return {module_name(p): p for p in files}


MODULES = package_modules()


DYNAMIC = "{any submodule}"  # an import_module() name only known at run time


def _is_import_module_call(node: ast.Call) -> bool:
    func = node.func
    return ((isinstance(func, ast.Attribute) and func.attr == "import_module")
            or (isinstance(func, ast.Name) and func.id in ("import_module", "__import__")))


def raw_imports(path: Path) -> Iterator[tuple[str, list[str], int]]:
    """Every import in ``path``: (absolute module, names imported from it, line).

    ``import a.b`` gives ("a.b", []); ``from a import b, c`` gives ("a", ["b", "c"]);
    relative imports are made absolute; ``import_module("a.b")`` gives ("a.b", []); an
    f-string ``import_module(f"artcal_ros.x.{v}")`` gives ("artcal_ros.x", [DYNAMIC]).
    """
    name = module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, [], node.lineno
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            yield module, [a.name for a in node.names], node.lineno
        elif isinstance(node, ast.Call) and _is_import_module_call(node) and node.args:
            arg = node.args[0]
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                yield arg.value, [], node.lineno
            elif (isinstance(arg, ast.JoinedStr) and arg.values
                  and isinstance(arg.values[0], ast.Constant)
                  and str(arg.values[0].value).endswith(".")):
                yield str(arg.values[0].value).rstrip("."), [DYNAMIC], node.lineno


def package_imports(path: Path) -> tuple[list[Import], list[str]]:
    """The artcal_ros modules that ``path`` imports, and its imports that name no module.

    Each import is an edge to the module it names; ``from p import m`` with ``m`` a
    submodule is an edge to ``p.m`` (and to ``p`` too if it also takes names defined in
    ``p``). Importing ``a.b.c`` also initialises ``a`` and ``a.b``: those count as implicit
    edges, except to the importer's own parent packages, which are necessarily initialised
    (or being initialised) before the importer runs.
    """
    importer = module_name(path)
    ancestors = {importer.rsplit(".", k)[0] for k in range(1, importer.count(".") + 1)}
    found: list[Import] = []
    unresolved: list[str] = []
    for module, names, line in raw_imports(path):
        if module.split(".")[0] != "artcal_ros":
            continue
        if module not in MODULES:
            unresolved.append(f"{path.relative_to(ROOT)}:{line}: {module}")
            continue
        if names == [DYNAMIC]:
            direct = [m for m in MODULES if m.startswith(module + ".")]
        else:
            submodules = [f"{module}.{n}" for n in names if f"{module}.{n}" in MODULES]
            # a plain ``import module``, or names defined in the module itself
            takes_names = not names or len(submodules) < len(names)
            direct = ([module] if takes_names else []) + submodules
        found += [Import(target, line) for target in direct if target != importer]
        for target in sorted({module, *direct}):
            parts = target.split(".")
            for k in range(1, len(parts) + 1):
                parent = ".".join(parts[:k])
                if parent not in ancestors and parent != importer and parent not in direct:
                    found.append(Import(parent, line, implicit=True))
    return found, unresolved


def import_graph() -> dict[str, dict[str, Import]]:
    """importer -> {imported module: the first import that makes the edge}."""
    graph: dict[str, dict[str, Import]] = {}
    for name, path in MODULES.items():
        edges: dict[str, Import] = {}
        for imp in package_imports(path)[0]:
            edges.setdefault(imp.target, imp)
        graph[name] = edges
    return graph


def strongly_connected(graph: dict[str, dict[str, Import]]) -> list[list[str]]:
    """Tarjan's strongly connected components of more than one module."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def a_cycle(graph: dict[str, dict[str, Import]], component: list[str]) -> list[str]:
    """One cycle through ``component[0]`` inside the component (shortest, by BFS)."""
    start, members = component[0], set(component)
    previous: dict[str, str] = {}
    frontier = [start]
    while frontier:
        following = []
        for v in frontier:
            for w in sorted(graph[v]):
                if w == start:
                    path = [v]
                    while path[-1] != start:
                        path.append(previous[path[-1]])
                    return [start, *reversed(path[:-1]), start]
                if w in members and w not in previous:
                    previous[w] = v
                    following.append(w)
        frontier = following
    raise AssertionError(f"no cycle in {component}")  # a component always has one


def describe(graph: dict[str, dict[str, Import]], cycle: list[str]) -> str:
    """``a -> b (a.py:12) -> ...``, marking implicit parent-package edges."""
    steps = [cycle[0]]
    for a, b in itertools.pairwise(cycle):
        imp = graph[a][b]
        how = " via its parent package" if imp.implicit else ""
        steps.append(f"-> {b} ({MODULES[a].relative_to(ROOT)}:{imp.line}{how})")
    return " ".join(steps)


def subpackage_files(sub: str) -> list[Path]:
    """Every module of ``artcal_ros/<sub>`` at any depth; fails if there is none."""
    directory = PACKAGE_DIR / sub
    assert (directory / "__init__.py").is_file(), f"artcal_ros/{sub} is not a package"
    files = sorted(p for p in directory.rglob("*.py") if "__pycache__" not in p.parts)
    assert len(files) > 1, f"artcal_ros/{sub} has no modules besides __init__.py"
    return files


def test_the_layout_test_sees_every_subpackage() -> None:
    """The rules below are checked against real files, not an empty list."""
    for sub in sorted(set(ROS_FREE) | set(FORBIDDEN)):
        subpackage_files(sub)
    assert {"artcal_ros.core.detect", "artcal_ros.core.calibrate",
            "artcal_ros.bag.reader", "artcal_ros.bag.writer"} <= set(MODULES)


@pytest.mark.parametrize("sub", ROS_FREE)
def test_ros_free_subpackage_imports_no_ros(sub: str) -> None:
    """No module of core/, synth/, bag/ (at any depth) imports a ROS module anywhere."""
    offenders = {}
    for path in subpackage_files(sub):
        ros = sorted({f"{m} (line {line})" for m, _, line in raw_imports(path)
                      if is_ros_module(m)})
        if ros:
            offenders[str(path.relative_to(ROOT))] = ros
    assert offenders == {}


def test_ros_free_subpackages_load_no_ros_when_imported() -> None:
    """Importing every module of core/, synth/ and bag/ (in a fresh interpreter) loads no ROS
    module, directly or through a third-party dependency."""
    names = sorted(name for name in MODULES
                   if name.split(".")[1:2] and name.split(".")[1] in ROS_FREE)
    assert names
    code = ("import importlib, json, sys\n"
            f"for name in {names!r}:\n"
            "    importlib.import_module(name)\n"
            "print(json.dumps(sorted(sys.modules)))\n")
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    loaded = json.loads(run.stdout.splitlines()[-1])
    assert sorted({m.split(".")[0] for m in loaded if is_ros_module(m)}) == []


def test_every_package_import_names_a_module() -> None:
    """No import of artcal_ros names a module that does not exist (a stale path)."""
    unresolved = [u for path in MODULES.values() for u in package_imports(path)[1]]
    assert unresolved == []


def test_imports_run_downward() -> None:
    """The layering rule: see FORBIDDEN."""
    offenders = []
    for name, path in MODULES.items():
        parts = name.split(".")
        if len(parts) < 2 or parts[1] not in FORBIDDEN:
            continue
        for imp in package_imports(path)[0]:
            target = imp.target.split(".")
            if not imp.implicit and len(target) > 1 and target[1] in FORBIDDEN[parts[1]]:
                offenders.append(f"{path.relative_to(ROOT)}:{imp.line}: {parts[1]} imports "
                                 f"{imp.target}")
    assert sorted(set(offenders)) == []


def test_no_import_cycle() -> None:
    graph = import_graph()
    assert sum(len(edges) for edges in graph.values()) > len(graph) // 2, "no imports seen?"
    cycles = [describe(graph, a_cycle(graph, c)) for c in strongly_connected(graph)]
    assert cycles == [], "import cycles:\n" + "\n".join(cycles)


def test_no_module_is_too_long() -> None:
    lengths = {str(p.relative_to(ROOT)): len(p.read_text().splitlines())
               for p in MODULES.values()}
    assert len(lengths) > 20
    too_long = {f: n for f, n in sorted(lengths.items()) if n > MAX_LINES}
    assert too_long == {}, f"modules over {MAX_LINES} lines: {too_long}"


DETECT = "artcal_ros.core.detect"


def stated_detect_layers() -> dict[str, int]:
    """core/detect/__init__.py's layer table (lines ``<n>  module  module ...``): module ->
    its layer number; fails if a module is listed twice."""
    doc = ast.get_docstring(ast.parse(MODULES[DETECT].read_text())) or ""
    layers: dict[str, int] = {}
    for line in doc.splitlines():
        words = line.split()
        if len(words) > 1 and words[0].isdigit() and line.startswith("    "):
            for word in words[1:]:
                assert word not in layers, f"{word} is in two layers of {DETECT}'s docstring"
                layers[word] = int(words[0])
    return layers


def test_detect_import_order_is_complete_and_kept() -> None:
    """Every module of core/detect/ is in the stated layers, and each of its imports of
    another (at any depth, in any function) goes down: to a module of a later layer."""
    layers = stated_detect_layers()
    modules = {name.removeprefix(DETECT + ".") for name in MODULES
               if name.startswith(DETECT + ".")}
    assert len(modules) > 20, "no detect modules seen?"
    assert sorted(modules - set(layers)) == [], "detect modules missing from the stated order"
    assert sorted(set(layers) - modules) == [], "stated order names modules that do not exist"
    upward = []
    for name in modules:
        path = MODULES[f"{DETECT}.{name}"]
        for imp in package_imports(path)[0]:
            target = imp.target.removeprefix(DETECT + ".")
            if not imp.implicit and target in layers and layers[target] <= layers[name]:
                upward.append(f"{path.relative_to(ROOT)}:{imp.line}: {name} (layer "
                              f"{layers[name]}) imports {target} (layer {layers[target]})")
    assert sorted(upward) == []


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
