"""``make demo`` leaves nothing under the user's home.

The demo (one pass of the sample bag, ``--once``) runs with ``HOME`` a fresh empty
directory; afterwards that directory is still empty, while the calibrator's saved session and
the ROS logs are in the demo's ``--out`` directory. Before, the session went to
``~/.ros/artcal/camera/`` and the next real run offered to resume the demo's views.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from artcal_ros.core.live.saved_session import FILE_NAME, load_session
from test.integration.ros_harness import ROOT

pytestmark = pytest.mark.integration


def test_the_demo_writes_nothing_under_home(tmp_path: Path) -> None:
    home, out = tmp_path / "home", tmp_path / "out"
    home.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("ROS_HOME", "ROS_LOG_DIR")}
    env["HOME"] = str(home)
    try:
        done = subprocess.run(
            [sys.executable, "-m", "artcal_ros.ros.demo", "--once", "--out", str(out),
             "--timeout", "240"], cwd=ROOT, env=env, capture_output=True, text=True,
            timeout=400, stdin=subprocess.DEVNULL, check=False)
    except subprocess.TimeoutExpired as e:
        raise AssertionError(f"the demo did not end: {e.stdout!r}") from None
    # One pass may give too few views on a busy machine (status 1): what it wrote counts.
    assert done.returncode in (0, 1), done.stdout + done.stderr
    left = sorted(str(p.relative_to(home)) for p in home.rglob("*"))
    assert left == [], f"the demo wrote under HOME: {left}"
    session = out / "ros_home" / "artcal" / "camera" / FILE_NAME
    assert len(load_session(session).views) > 0, done.stdout
    assert any((out / "ros_home" / "log").iterdir()), "no ROS logs in the demo's directory"
    assert (out / "calibrator.log").is_file()
    # the progress line's counts are explained before the first one (issue 26, point 10)
    legend = done.stdout.find("measured (detected precisely")
    first = done.stdout.find("  frames seen")
    assert 0 <= legend < first, done.stdout
