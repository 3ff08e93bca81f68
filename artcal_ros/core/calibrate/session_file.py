"""The node's saved session: the views collected so far, on disk, safe against a kill.

The calibrator keeps its views (detections, never images) in
``~/.ros/artcal/<camera_name>/session.npz`` (``~`` is ``$HOME``), rewritten atomically
(temporary file, fsync, rename) every few seconds while the collection changes and once
more on a clean stop. After a crash or ``kill -9`` at most those few seconds are lost:
started again with ``resume: true``, the node continues with the saved views. A file
that is not a session, is of another format version, or was made with another board is
refused with the reason and the node starts empty.

The file is a NumPy ``.npz`` archive read with ``allow_pickle=False`` (a damaged or
foreign file cannot run code). Arrays, with M the markers of all views together and V
the views:

    meta            () str: JSON {"format", "board", "image_size", "saved_unix_s", "views"}
    ids             (M,) int64
    corners_px      (M, 4, 2) float64, pixels
    centers_px      (M, 2) float64, pixels
    corner_sigma_px (M, 4) float64, pixels
    center_sigma_px (M,) float64, pixels
    view_offsets    (V + 1,) int64: view k holds markers view_offsets[k]:view_offsets[k + 1]
    sharpness       (V,) float64
"""

from __future__ import annotations

import json
import os
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.coverage import ViewCollector
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError

FORMAT = "artcal-session-1"
FILE_NAME = "session.npz"
PREVIOUS_NAME = "session.previous.npz"
SAVE_PERIOD_S = 2.0


class SessionFileError(ArtcalError):
    """A saved session cannot be used (not a session, another format, another board)."""


def session_dir(camera_name: str) -> Path:
    """``~/.ros/artcal/<camera_name>/`` (``~`` from ``$HOME``)."""
    return Path.home() / ".ros" / "artcal" / camera_name


def board_signature(board: Board) -> dict[str, Any]:
    """What must match for saved views to belong to ``board``: layout, sizes, ids."""
    return {"cols": board.cols, "rows": board.rows, "first_id": board.first_id,
            "dictionary": board.dictionary_name,
            "marker_length": round(float(board.marker_length), 9),
            "marker_separation": round(float(board.marker_separation), 9)}


@dataclass(frozen=True)
class SavedSession:
    """A session read back.

    Attributes:
        views: the views, oldest first (all of ``image_size``).
        image_size: (width, height) of the views, pixels; None with no views.
        saved_unix_s: when it was written, seconds since the epoch.
    """

    views: list[Detections]
    image_size: tuple[int, int] | None
    saved_unix_s: float


def _fsync_dir(path: Path) -> None:
    # The rename itself reaches the disk only when the directory is synced too.
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_session(path: Path, views: Sequence[Detections], board: Board) -> None:
    """Write ``views`` atomically: a reader (or a restart after a kill) sees the old file
    or the new one, whole.

    Raises:
        OSError: the directory or the file cannot be written (the old file is untouched).
    """
    sizes = {tuple(int(x) for x in v.image_size) for v in views}
    if len(sizes) > 1:
        raise SessionFileError(f"views of several image sizes {sorted(sizes)}; not saved")
    offsets = np.cumsum([0, *(len(v) for v in views)]).astype(np.int64)

    def cat(name: str, shape: tuple[int, ...]) -> np.ndarray:
        parts = [np.asarray(getattr(v, name), np.float64).reshape(-1, *shape) for v in views]
        return np.concatenate(parts) if parts else np.zeros((0, *shape))

    meta = {"format": FORMAT, "board": board_signature(board),
            "image_size": list(sizes.pop()) if sizes else None,
            "saved_unix_s": time.time(), "views": len(views)}
    arrays: dict[str, Any] = {
        "meta": np.array(json.dumps(meta)),
        "ids": np.concatenate([v.ids for v in views]).astype(np.int64) if views
        else np.zeros(0, np.int64),
        "corners_px": cat("corners_px", (4, 2)), "centers_px": cat("centers_px", (2,)),
        "corner_sigma_px": cat("corner_sigma_px", (4,)),
        "center_sigma_px": cat("center_sigma_px", ()),
        "view_offsets": offsets,
        "sharpness": np.array([v.sharpness for v in views], np.float64),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=str(path.parent))
    try:
        with os.fdopen(fd, "wb") as f:
            np.savez(f, allow_pickle=False, **arrays)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def read_session(path: Path, board: Board) -> SavedSession:
    """Read a session written by :func:`write_session` for ``board``.

    Raises:
        SessionFileError: the file is missing, damaged, of another format, or of another
            board (the message says which and what was expected).
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if not isinstance(meta, dict) or meta.get("format") != FORMAT:
                found = meta.get("format") if isinstance(meta, dict) else None
                raise SessionFileError(f"{path} is of format {found!r}, not {FORMAT!r}")
            data = {k: np.asarray(z[k]) for k in (
                "ids", "corners_px", "centers_px", "corner_sigma_px", "center_sigma_px",
                "view_offsets", "sharpness")}
    except SessionFileError:
        raise
    except FileNotFoundError:
        raise SessionFileError(f"{path} does not exist") from None
    except Exception as e:  # zip, npy, JSON or key errors: all mean a damaged file
        raise SessionFileError(f"{path} is not a readable session ({type(e).__name__}: "
                               f"{e})") from None
    want = board_signature(board)
    if meta.get("board") != want:
        raise SessionFileError(f"{path} was made with another board ({meta.get('board')}); "
                               f"this node's board is {want}")
    try:
        size = meta["image_size"]
        image_size = None if size is None else (int(size[0]), int(size[1]))
        views = _views(data, image_size)
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise SessionFileError(f"{path} holds inconsistent views ({e})") from None
    if len(views) != int(meta.get("views", -1)):
        raise SessionFileError(f"{path} says {meta.get('views')} views but holds {len(views)}")
    return SavedSession(views, image_size, float(meta.get("saved_unix_s", 0.0)))


def _views(data: dict[str, np.ndarray], image_size: tuple[int, int] | None
           ) -> list[Detections]:
    offsets = data["view_offsets"].astype(np.int64)
    m = len(data["ids"])
    if offsets.ndim != 1 or len(offsets) < 1 or offsets[0] != 0 or offsets[-1] != m \
            or np.any(np.diff(offsets) < 0) or len(data["sharpness"]) != len(offsets) - 1:
        raise ValueError("view offsets do not match the markers")
    if len(offsets) > 1 and image_size is None:
        raise ValueError("views without an image size")
    if image_size is not None and (image_size[0] <= 0 or image_size[1] <= 0):
        raise ValueError(f"image size {image_size}")
    out = []
    for k in range(len(offsets) - 1):
        s = slice(int(offsets[k]), int(offsets[k + 1]))
        assert image_size is not None
        out.append(Detections(data["ids"][s], data["corners_px"][s], data["centers_px"][s],
                              image_size, data["corner_sigma_px"][s],
                              data["center_sigma_px"][s], float(data["sharpness"][k]),
                              source=f"resumed view {k}"))
    return out


class SessionStore:
    """Keeps a :class:`ViewCollector`'s views saved in a session file.

    :meth:`open` restores (``resume``) or announces an old session; :meth:`start` begins
    saving every ``period_s`` while the views change; :meth:`close` saves a last time.
    Saving runs on its own daemon thread and never blocks the collection for longer
    than a copy of its view list.

    Args:
        path: the session file (:func:`session_dir` / :data:`FILE_NAME`).
        board: the board of the views.
        collector: the collection to save and to restore into.
        warn: called with a one-line message when saving fails (once per distinct reason).
        period_s: seconds between checks for a change.
    """

    def __init__(self, path: Path, board: Board, collector: ViewCollector, *,
                 warn: Callable[[str], None], period_s: float = SAVE_PERIOD_S) -> None:
        self.path = path
        self.board = board
        self.collector = collector
        self._warn = warn
        self._period_s = period_s
        self._saved: list[Detections] | None = None  # the views as last written
        self._keep_previous = False
        self._last_error = ""
        self._lock = threading.Lock()  # one save at a time (the thread, close)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.saves = 0

    def open(self, *, resume: bool) -> list[str]:
        """Restore the saved views into the collector (``resume``), or leave them and say
        how to resume. Returns the messages for the log, warnings prefixed ``WARN: ``."""
        if not self.path.exists():
            return [f"session: none saved yet; views will be saved in {self.path}"] \
                if resume else []
        try:
            saved = read_session(self.path, self.board)
        except SessionFileError as e:
            self._keep_previous = True
            return [f"WARN: session not resumed, starting empty: {e}; it is kept as "
                    f"{self.path.with_name(PREVIOUS_NAME)} once new views are saved"]
        age = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(saved.saved_unix_s))
        if not resume:
            self._keep_previous = True
            return [f"an earlier session of {len(saved.views)} views (saved {age}) is in "
                    f"{self.path}; to continue it, restart with -p resume:=true (starting "
                    f"empty; it is kept as {PREVIOUS_NAME} once new views are saved)"]
        kept = sum(1 for v in saved.views if self.collector.add(v))
        self._saved = self.collector.views
        note = "" if kept == len(saved.views) else \
            f" ({len(saved.views) - kept} no longer pass the collection's checks)"
        return [f"resumed {kept} views saved {age} from {self.path}{note}"]

    def start(self) -> None:
        """Begin saving in the background."""
        self._thread = threading.Thread(target=self._run, name="session", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(self._period_s):
            self.save_if_changed()

    def save_if_changed(self) -> bool:
        """Write the views if they changed since the last write; whether it wrote."""
        with self._lock:
            views = self.collector.views
            old = self._saved
            if old is not None and len(old) == len(views) and all(
                    a is b for a, b in zip(old, views, strict=True)):
                return False
            if old is None and not views:
                return False  # nothing collected and nothing saved: leave an old file be
            size = self.collector.image_size
            if old and views and size is not None and size != old[0].image_size:
                # The collection restarted on another image size: the saved views are of
                # another camera mode, not to be overwritten without a word.
                self._keep_previous = True
                self._warn(f"the camera now sends {size[0]}x{size[1]} images but the saved "
                           f"views are {old[0].image_size[0]}x{old[0].image_size[1]}: "
                           f"collecting anew; the old views are kept as {PREVIOUS_NAME}")
            try:
                if self._keep_previous and self.path.exists():
                    os.replace(self.path, self.path.with_name(PREVIOUS_NAME))
                self._keep_previous = False
                write_session(self.path, views, self.board)
            except (OSError, SessionFileError) as e:
                reason = f"cannot save the session in {self.path}: " \
                    f"{getattr(e, 'strerror', None) or e}"
                if reason != self._last_error:
                    self._last_error = reason
                    self._warn(f"{reason}; views are kept in memory and saving is retried")
                return False
            self._last_error = ""
            self._saved = views
            self.saves += 1
            return True

    def close(self) -> None:
        """Stop the background saving and save a last time if anything changed."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        self.save_if_changed()
