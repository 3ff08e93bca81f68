"""The calibration YAML under a kill and a failing disk.

A writer process rewrites one path over and over with two large calibrations and is
SIGKILLed at random moments; after every kill the file parses as one of the two, whole.
A full disk (fsync failing with ENOSPC), a parent that is a file, and a directory as the
output path each leave the old file untouched and name the path and the reason.
"""

from __future__ import annotations

import errno
import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from artcal_ros.core.camera_info import (
    CameraInfoData,
    read_camera_info_yaml,
    write_camera_info_yaml,
)
from artcal_ros.core.errors import ArtcalError
from artcal_ros.synth import Camera

ROOT = Path(__file__).resolve().parents[2]
KILLS = 20
# camera_name padded to ~300 kB: a write and its fsync take milliseconds, long enough to
# be cut in two (a plain open().write() over the path fails this test at the first kill).
NAME_CHARS = 300_000

WRITER = textwrap.dedent("""
    import sys

    import numpy as np

    from artcal_ros.core.camera_info import CameraInfoData, write_camera_info_yaml

    path, n = sys.argv[1], int(sys.argv[2])
    cams = []
    for tag, f in (("a", 500.0), ("b", 900.0)):
        K = np.array([[f, 0.0, 319.5], [0.0, f, 239.5], [0.0, 0.0, 1.0]])
        cams.append(CameraInfoData((640, 480), tag * n, K, "plumb_bob", np.zeros(5),
                                   np.eye(3), np.hstack([K, np.zeros((3, 1))])))
    print("ready", flush=True)
    k = 0
    while True:
        write_camera_info_yaml(path, cams[k % 2])
        k += 1
""")


def test_a_kill_during_a_write_leaves_the_old_or_the_new_file(tmp_path: Path) -> None:
    path = tmp_path / "camera.yaml"
    expected = {"a": 500.0, "b": 900.0}
    rng = random.Random(11)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])}
    seen = set()
    for _ in range(KILLS):
        proc = subprocess.Popen([sys.executable, "-c", WRITER, str(path), str(NAME_CHARS)],
                                stdout=subprocess.PIPE, env=env)
        assert proc.stdout is not None and proc.stdout.readline().strip() == b"ready"
        deadline = time.monotonic() + 30
        while not path.exists():  # the first write of the first run
            assert time.monotonic() < deadline, "the writer wrote nothing"
            time.sleep(0.01)
        time.sleep(rng.uniform(0.0, 0.3))
        proc.send_signal(signal.SIGKILL)
        proc.wait(10)
        proc.stdout.close()
        info = read_camera_info_yaml(path)  # raises on a partial file
        tag = info.camera_name[0]
        assert info.camera_name == tag * NAME_CHARS, "a partial camera_name"
        assert info.camera_matrix[0, 0] == info.camera_matrix[1, 1] == expected[tag]
        seen.add(tag)
    assert seen == {"a", "b"}, "kills landed after both calibrations"


def calibration(preset: str = "webcam") -> CameraInfoData:
    return CameraInfoData.from_camera(Camera.preset(preset), "cam")


def test_a_full_disk_names_the_path_and_keeps_the_old_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "camera.yaml"
    write_camera_info_yaml(path, calibration("webcam"))
    before = path.read_bytes()

    def full(_fd: int) -> None:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(os, "fsync", full)
    with pytest.raises(ArtcalError) as e:
        write_camera_info_yaml(path, calibration("wide"))
    assert str(path) in str(e.value) and "No space left on device" in str(e.value)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["camera.yaml"], "temp file left"


def test_a_parent_that_is_a_file_or_a_directory_as_output_is_named(tmp_path: Path) -> None:
    blocker = tmp_path / "not_a_dir"
    blocker.write_text("x")
    with pytest.raises(ArtcalError, match="not_a_dir is a file, not a directory") as e:
        write_camera_info_yaml(blocker / "sub" / "camera.yaml", calibration())
    assert str(blocker / "sub" / "camera.yaml") in str(e.value)
    with pytest.raises(ArtcalError, match="it is a directory"):
        write_camera_info_yaml(tmp_path, calibration())


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only directories")
def test_a_read_only_directory_is_named(tmp_path: Path) -> None:
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(ArtcalError, match="Permission denied") as e:
            write_camera_info_yaml(ro / "camera.yaml", calibration())
        assert str(ro / "camera.yaml") in str(e.value)
    finally:
        ro.chmod(0o700)


def test_every_result_file_gets_the_mode_the_umask_gives(tmp_path: Path) -> None:
    # one atomic writer serves the YAML, the camchain and truth.json; mkstemp alone would
    # leave each readable by its owner only
    from artcal_ros.core.camchain import write_text_atomic
    from artcal_ros.synth.truth import write_json_atomic

    old = os.umask(0o022)
    try:
        written = [write_camera_info_yaml(tmp_path / "camera.yaml", calibration()),
                   write_text_atomic(tmp_path / "camchain.yaml", "cam0: {}\n")]
        write_json_atomic(tmp_path / "deep" / "truth.json", {"frames": []})
        written.append(tmp_path / "deep" / "truth.json")
    finally:
        os.umask(old)
    for path in written:
        assert path.stat().st_mode & 0o777 == 0o644, path
    assert (tmp_path / "deep" / "truth.json").read_text() == '{"frames":[]}\n'
