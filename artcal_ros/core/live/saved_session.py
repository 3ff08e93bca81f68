"""The node's saved session: the views collected so far, on disk, safe against a kill.

The calibrator keeps its views (detections, never images) in
``$ROS_HOME/artcal/<camera_name>/session.npz`` (``ROS_HOME`` as rcl reads it for its logs:
``~/.ros`` unless set), rewritten atomically (temporary file, fsync, rename) every few
seconds while the collection changes and once more on a clean stop. After a crash or
``kill -9`` at most those few seconds are lost: started again with ``resume: true``, the
node continues with the saved views. A file that is not a session or is of another format
version is refused with the reason and the node starts empty.

The file also says where its views came from (:class:`SessionSource`: camera name, image
topic, board). A resume of views from another board or image topic is refused
(:class:`SessionMismatchError`): they would mix another camera's views into this one's
calibration. Files from before the source was recorded still load; their board is checked.

The file is a NumPy ``.npz`` archive read with ``allow_pickle=False`` (a damaged or
foreign file cannot run code). Arrays, with M the markers of all views together and V
the views:

    meta            () str: JSON {"format", "board", "image_size", "saved_unix_s", "views",
                    "source" (optional: {"camera_name", "image_topic", "board"})}
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
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError
from artcal_ros.core.files import ros_home
from artcal_ros.core.live.coverage import ViewCollector

FORMAT = "artcal-session-1"
FILE_NAME = "session.npz"
PREVIOUS_NAME = "session.previous.npz"
SAVE_PERIOD_S = 2.0


class SessionFileError(ArtcalError):
    """A saved session cannot be used (not a session, another format, another board)."""


class SessionMismatchError(SessionFileError):
    """A saved session is of another board or image topic than the node resuming it."""


def session_dir(camera_name: str) -> Path:
    """``$ROS_HOME/artcal/<camera_name>/`` (``~/.ros/artcal/<camera_name>/`` by default)."""
    return ros_home() / "artcal" / camera_name


def board_signature(board: Board) -> dict[str, Any]:
    """What must match for saved views to belong to ``board``: type, layout, sizes, ids."""
    return {"type": board.board_type, "cols": board.cols, "rows": board.rows,
            "first_id": board.first_id, "dictionary": board.dictionary_name,
            "marker_length": round(float(board.marker_length), 9),
            "marker_separation": round(float(board.marker_separation), 9),
            "square_length": round(float(board.square_length), 9)}


def same_board(saved: dict[str, Any], board: Board) -> bool:
    """Whether a saved signature is ``board``'s. Older files hold fewer keys (no type, no
    square length): only the keys they hold are compared."""
    want = board_signature(board)
    return isinstance(saved, dict) and set(saved) <= set(want) and bool(saved) \
        and all(saved[k] == want[k] for k in saved)


def _signature_text(signature: dict[str, Any]) -> str:
    # An older file's board, in words (it holds no description of its own).
    try:
        return (f"{signature['cols']}x{signature['rows']} {signature['dictionary']} ids from "
                f"{signature['first_id']}, marker {signature['marker_length'] * 1000:g} mm, "
                f"gap {signature['marker_separation'] * 1000:g} mm")
    except (KeyError, TypeError):
        return str(signature)


@dataclass(frozen=True)
class SessionSource:
    """Where a session's views come from.

    Attributes:
        camera_name: the node's ``camera_name`` (the session directory's name).
        image_topic: the image topic as the node resolved it (remappings applied).
        board: the board in words (:meth:`Board.describe`).
    """

    camera_name: str
    image_topic: str
    board: str

    def as_json(self) -> dict[str, str]:
        return {"camera_name": self.camera_name, "image_topic": self.image_topic,
                "board": self.board}

    @classmethod
    def from_json(cls, value: Any) -> SessionSource | None:
        """The source saved in a file's meta; None for a file without one (or a bad one)."""
        if not isinstance(value, dict):
            return None
        fields = [value.get(k) for k in ("camera_name", "image_topic", "board")]
        if not all(isinstance(f, str) for f in fields):
            return None
        return cls(*(str(f) for f in fields))


@dataclass(frozen=True)
class SavedSession:
    """A session read back.

    Attributes:
        views: the views, oldest first (all of ``image_size``).
        image_size: (width, height) of the views, pixels; None with no views.
        saved_unix_s: when it was written, seconds since the epoch.
        board_signature: the board's :func:`board_signature` as saved.
        source: where the views came from; None in a file written before it was recorded.
    """

    views: list[Detections]
    image_size: tuple[int, int] | None
    saved_unix_s: float
    board_signature: dict[str, Any]
    source: SessionSource | None = None

    def difference(self, board: Board, source: SessionSource | None) -> tuple[str, str] | None:
        """(what these views were recorded from, what ``source`` reads) in words when the
        board or the image topic differs, else None. Without a saved source (an older file)
        or without ``source`` only the board is compared."""
        other_board = not same_board(self.board_signature, board)
        other_topic = self.source is not None and source is not None \
            and self.source.image_topic != source.image_topic
        if not (other_board or other_topic):
            return None
        size = f" of {self.image_size[0]}x{self.image_size[1]} images" \
            if self.image_size else ""
        if self.source is not None:
            theirs = (f"camera_name '{self.source.camera_name}': {len(self.views)} views{size} "
                      f"recorded from {self.source.image_topic} with board {self.source.board}")
        else:
            theirs = (f"{len(self.views)} views{size} recorded with board "
                      f"{_signature_text(self.board_signature)}")
        ours = f"with board {board.describe()}" if source is None else \
            f"{source.image_topic} with board {source.board}"
        return theirs, ours


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


def write_session(path: Path, views: Sequence[Detections], board: Board,
                  source: SessionSource | None = None) -> None:
    """Write ``views`` atomically: a reader (or a restart after a kill) sees the old file
    or the new one, whole. ``source``: where they came from (saved with them).

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
            "saved_unix_s": time.time(), "views": len(views),
            "source": source.as_json() if source is not None else None}
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
        SessionFileError: the file is missing, damaged or of another format;
            SessionMismatchError: of another board (the message says which and what was
            expected).
    """
    saved = load_session(path)
    if not same_board(saved.board_signature, board):
        raise SessionMismatchError(f"{path} was made with another board "
                                   f"({saved.board_signature}); this node's board is "
                                   f"{board_signature(board)}")
    return saved


def load_session(path: Path) -> SavedSession:
    """Read a session written by :func:`write_session`, of whichever board.

    Raises:
        SessionFileError: the file is missing, damaged, or of another format (the message
            says which).
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
    try:
        size = meta["image_size"]
        image_size = None if size is None else (int(size[0]), int(size[1]))
        views = _views(data, image_size)
    except (KeyError, TypeError, ValueError, IndexError) as e:
        raise SessionFileError(f"{path} holds inconsistent views ({e})") from None
    if len(views) != int(meta.get("views", -1)):
        raise SessionFileError(f"{path} says {meta.get('views')} views but holds {len(views)}")
    signature = meta.get("board")
    return SavedSession(views, image_size, float(meta.get("saved_unix_s", 0.0)),
                        signature if isinstance(signature, dict) else {},
                        SessionSource.from_json(meta.get("source")))


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
        source: where the views come from: saved with them, and a saved session of another
            image topic is not resumed (None: only the board is compared).
    """

    def __init__(self, path: Path, board: Board, collector: ViewCollector, *,
                 warn: Callable[[str], None], period_s: float = SAVE_PERIOD_S,
                 source: SessionSource | None = None) -> None:
        self.path = path
        self.board = board
        self.source = source
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
        how to resume. Returns the messages for the log, warnings prefixed ``WARN: ``.

        Raises:
            SessionMismatchError: ``resume`` of views from another board or image topic
                (the message says whose they are and what to do).
        """
        if not self.path.exists():
            return [f"session: none saved yet; views will be saved in {self.path}"] \
                if resume else []
        try:
            saved = load_session(self.path)
        except SessionFileError as e:
            self._keep_previous = True
            return [f"WARN: session not resumed, starting empty: {e}; it is kept as "
                    f"{self.path.with_name(PREVIOUS_NAME)} once new views are saved"]
        age = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(saved.saved_unix_s))
        difference = saved.difference(self.board, self.source)
        if difference is not None:
            theirs, ours = difference
            if resume:
                raise SessionMismatchError(
                    f"the saved session in {self.path.parent}/ ({theirs}, saved {age}) is not "
                    f"this camera's: this node reads {ours}; start without resume:=true (the "
                    f"saved views are then kept as {PREVIOUS_NAME}), or give this camera its "
                    "own camera_name")
            self._keep_previous = True
            return [f"an earlier session in {self.path} is of another camera or board "
                    f"({theirs}, saved {age}); starting empty (it is kept as {PREVIOUS_NAME} "
                    "once new views are saved)"]
        if not resume:
            self._keep_previous = True
            return [f"an earlier session of {len(saved.views)} views (saved {age}) is in "
                    f"{self.path}; to continue it, restart with -p resume:=true (starting "
                    f"empty; it is kept as {PREVIOUS_NAME} once new views are saved)"]
        kept = sum(1 for v in saved.views if self.collector.add(v))
        self._saved = self.collector.views
        note = "" if kept == len(saved.views) else \
            f" ({len(saved.views) - kept} no longer pass the collection's checks)"
        lines = [f"resumed {kept} views saved {age} from {self.path}{note}"]
        if saved.source is None and self.source is not None:
            lines.append("the session file does not say which image topic its views came "
                         "from (an older version saved it): resumed as this camera's, its "
                         "board checked; the next save records the source")
        return lines

    def start(self) -> None:
        """Begin saving in the background (once; :meth:`close` ends it)."""
        if self._thread is not None:
            return
        self._thread = threading.Thread(target=self._run, name="save session", daemon=True)
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
                write_session(self.path, views, self.board, self.source)
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

    @property
    def alive(self) -> bool:
        """Whether the background saving still runs."""
        return self._thread is not None and self._thread.is_alive()

    def close(self, timeout: float = 5.0) -> None:
        """Stop the background saving (waiting up to ``timeout`` s for its thread) and save
        a last time if anything changed. Idempotent."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
        self.save_if_changed()
