"""The node's saved session: views written and read back exactly, damaged, foreign and
other-board files refused with the reason, the store saving only on change and keeping an
old session it did not resume; the session's source (camera, image topic, board) saved with
it, and a resume of another source refused with whose it is and what to do."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.coverage import CoverageConfig, ViewCollector
from artcal_ros.core.live.saved_session import (
    FILE_NAME,
    PREVIOUS_NAME,
    SessionFileError,
    SessionMismatchError,
    SessionSource,
    SessionStore,
    load_session,
    read_session,
    session_dir,
    write_session,
)
from artcal_ros.synth import Camera, random_poses
from artcal_ros.synth.poses import marker_truth

BOARD = Board()


def views(n: int, seed: int = 3, preset: str = "webcam") -> list[Detections]:
    cam = Camera.preset(preset)
    rng = np.random.default_rng(seed)
    out = []
    for k, (rvec, tvec) in enumerate(random_poses(BOARD, cam, n, rng)):
        corners, _, inside, _ = marker_truth(BOARD, cam, rvec, tvec)
        noisy = corners[inside] + rng.normal(0.0, 0.05, corners[inside].shape)
        out.append(Detections(BOARD.ids[inside], noisy, noisy.mean(axis=1), cam.size,
                              corner_sigma_px=np.full((int(inside.sum()), 4), 0.1),
                              sharpness=10.0 + k, source=f"v{k}"))
    return out


def test_views_read_back_exactly(tmp_path: Path) -> None:
    saved = views(5)
    path = tmp_path / "s" / FILE_NAME
    write_session(path, saved, BOARD)
    back = read_session(path, BOARD)
    assert back.image_size == saved[0].image_size and len(back.views) == 5
    for a, b in zip(saved, back.views, strict=True):
        np.testing.assert_array_equal(a.ids, b.ids)
        np.testing.assert_array_equal(a.corners_px, b.corners_px)
        np.testing.assert_array_equal(a.centers_px, b.centers_px)
        np.testing.assert_array_equal(a.corner_sigma_px, b.corner_sigma_px)
        assert a.sharpness == b.sharpness
    assert not [p for p in path.parent.iterdir() if p.name != FILE_NAME], "temp file left"


def test_an_empty_session_reads_back_empty(tmp_path: Path) -> None:
    write_session(tmp_path / FILE_NAME, [], BOARD)
    back = read_session(tmp_path / FILE_NAME, BOARD)
    assert back.views == [] and back.image_size is None


def test_the_session_dir_follows_home(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("ROS_HOME", raising=False)
    assert session_dir("cam1") == tmp_path / ".ros" / "artcal" / "cam1"


def test_the_session_dir_follows_ros_home(tmp_path: Path,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.setenv("ROS_HOME", str(tmp_path / "ros"))
    assert session_dir("cam1") == tmp_path / "ros" / "artcal" / "cam1"


@pytest.mark.parametrize(("content", "reason"), [
    (b"", "not a readable session"),
    (b"garbage \x00\x01 not a zip", "not a readable session"),
    (b"PK\x03\x04 truncated zip", "not a readable session"),
])
def test_a_damaged_file_is_refused(tmp_path: Path, content: bytes, reason: str) -> None:
    path = tmp_path / FILE_NAME
    path.write_bytes(content)
    with pytest.raises(SessionFileError, match=reason):
        read_session(path, BOARD)


def test_a_truncated_session_is_refused(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    write_session(path, views(3), BOARD)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(SessionFileError, match="not a readable session"):
        read_session(path, BOARD)


def test_another_board_is_refused_naming_both(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    write_session(path, views(2), BOARD)
    other = Board(cols=10, rows=7, dictionary_name="DICT_4X4_250")
    with pytest.raises(SessionFileError, match="another board") as e:
        read_session(path, other)
    assert "DICT_4X4_250" in str(e.value) and "DICT_6X6_1000" in str(e.value)


def test_another_format_and_inconsistent_views_are_refused(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    meta = {"format": "something-else-7", "board": {}, "image_size": None, "views": 0}
    np.savez(path.open("wb"), meta=np.array(json.dumps(meta)))
    with pytest.raises(SessionFileError, match="something-else-7"):
        read_session(path, BOARD)
    write_session(path, views(2), BOARD)
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["view_offsets"] = arrays["view_offsets"] + 1  # points past the markers
    with path.open("wb") as f:
        np.savez(f, **arrays)
    with pytest.raises(SessionFileError, match="inconsistent"):
        read_session(path, BOARD)


def collector() -> ViewCollector:
    return ViewCollector(BOARD, CoverageConfig(min_views=3))


def test_store_resumes_saves_on_change_only_and_keeps_what_it_did_not_resume(
        tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    first = collector()
    warnings: list[str] = []
    store = SessionStore(path, BOARD, first, warn=warnings.append)
    assert store.open(resume=False) == []  # nothing saved yet: nothing to say
    assert not store.save_if_changed(), "nothing collected: nothing written"
    for v in views(4):
        first.add(v)
    assert store.save_if_changed() and not store.save_if_changed()
    assert len(read_session(path, BOARD).views) == len(first.views) == 4

    resumed = collector()
    lines = SessionStore(path, BOARD, resumed, warn=warnings.append).open(resume=True)
    assert len(resumed.views) == 4 and "resumed 4 views" in lines[0]

    fresh = collector()
    store = SessionStore(path, BOARD, fresh, warn=warnings.append)
    lines = store.open(resume=False)
    assert "resume:=true" in lines[0] and "4 views" in lines[0] and not fresh.views
    fresh.add(views(1, seed=9)[0])
    assert store.save_if_changed()
    assert len(read_session(path, BOARD).views) == 1
    assert len(read_session(path.with_name(PREVIOUS_NAME), BOARD).views) == 4
    assert warnings == []


def test_store_refuses_a_damaged_file_and_starts_empty(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    path.write_bytes(b"\x00" * 100)
    c = collector()
    lines = SessionStore(path, BOARD, c, warn=print).open(resume=True)
    assert lines[0].startswith("WARN: session not resumed, starting empty") and not c.views


def test_a_failed_save_warns_once_and_keeps_the_views(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("a file where the session directory should be")
    c = collector()
    warnings: list[str] = []
    store = SessionStore(blocker / FILE_NAME, BOARD, c, warn=warnings.append)
    for v in views(2):
        c.add(v)
    assert not store.save_if_changed() and not store.save_if_changed()
    assert len(warnings) == 1 and str(blocker) in warnings[0] and len(c.views) == 2


def test_another_image_size_after_a_resume_keeps_the_old_views(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    write_session(path, views(3), BOARD)  # 640 x 480
    c = collector()
    warnings: list[str] = []
    store = SessionStore(path, BOARD, c, warn=warnings.append)
    store.open(resume=True)
    assert len(c.views) == 3
    assert c.add(views(1, seed=5, preset="wide")[0])  # 1280 x 800: the collection restarts
    assert store.save_if_changed()
    assert len(warnings) == 1 and "1280x800" in warnings[0] and "640x480" in warnings[0]
    assert len(read_session(path.with_name(PREVIOUS_NAME), BOARD).views) == 3
    assert read_session(path, BOARD).image_size == (1280, 800)


DEMO = SessionSource("camera", "/demo/image", BOARD.describe())
REAL = SessionSource("camera", "/camera/image_raw", BOARD.describe())


def make_old(path: Path) -> None:
    """Rewrite a session as the versions before the source was saved wrote it."""
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"]))
    del meta["source"], meta["board"]["type"], meta["board"]["square_length"]
    arrays["meta"] = np.array(json.dumps(meta))
    with path.open("wb") as f:
        np.savez(f, **arrays)


def test_the_source_is_saved_with_the_views(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    write_session(path, views(3), BOARD, DEMO)
    back = load_session(path)
    assert back.source == DEMO and len(back.views) == 3
    assert back.difference(BOARD, DEMO) is None
    write_session(path, views(3), BOARD)
    assert load_session(path).source is None


def test_a_resume_from_another_image_topic_is_refused_saying_whose_and_what_to_do(
        tmp_path: Path) -> None:
    path = tmp_path / "camera" / FILE_NAME
    write_session(path, views(3), BOARD, DEMO)
    c = collector()
    store = SessionStore(path, BOARD, c, warn=print, source=REAL)
    with pytest.raises(SessionMismatchError) as e:
        store.open(resume=True)
    text = str(e.value)
    assert "\n" not in text and not c.views
    assert f"{path.parent}/" in text and "3 views of 640x480 images" in text
    assert "recorded from /demo/image" in text and "this node reads /camera/image_raw" in text
    assert "start without resume:=true" in text and "camera_name" in text
    assert BOARD.describe() in text


def test_a_resume_with_another_board_is_refused_naming_both(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    write_session(path, views(2), BOARD, REAL)
    other = Board(cols=10, rows=7, dictionary_name="DICT_4X4_250")
    source = SessionSource("camera", REAL.image_topic, other.describe())
    with pytest.raises(SessionMismatchError) as e:
        SessionStore(path, other, collector(), warn=print, source=source).open(resume=True)
    assert f"with board {BOARD.describe()}" in str(e.value)
    assert f"reads /camera/image_raw with board {other.describe()}" in str(e.value)
    chess = Board(board_type="chessboard", cols=BOARD.cols, rows=BOARD.rows)
    with pytest.raises(SessionMismatchError, match="chessboard"):
        SessionStore(path, chess, collector(), warn=print).open(resume=True)


def test_without_resume_another_source_is_not_offered_for_resume(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    write_session(path, views(3), BOARD, DEMO)
    c = collector()
    store = SessionStore(path, BOARD, c, warn=print, source=REAL)
    lines = store.open(resume=False)
    assert len(lines) == 1 and "another camera or board" in lines[0]
    assert "/demo/image" in lines[0] and "resume:=true" not in lines[0] and not c.views
    c.add(views(1, seed=9)[0])
    assert store.save_if_changed()
    assert load_session(path).source == REAL
    assert load_session(path.with_name(PREVIOUS_NAME)).source == DEMO


def test_an_older_file_without_its_source_still_resumes_and_says_so(tmp_path: Path) -> None:
    path = tmp_path / FILE_NAME
    write_session(path, views(3), BOARD, DEMO)
    make_old(path)
    assert load_session(path).source is None
    c = collector()
    lines = SessionStore(path, BOARD, c, warn=print, source=REAL).open(resume=True)
    assert len(c.views) == 3 and "resumed 3 views" in lines[0]
    assert "does not say which image topic" in lines[1]
    other = Board(cols=10, rows=7, dictionary_name="DICT_4X4_250")
    with pytest.raises(SessionMismatchError) as e:
        SessionStore(path, other, collector(), warn=print).open(resume=True)
    assert "19x9 DICT_6X6_1000" in str(e.value) and "recorded with board" in str(e.value)
