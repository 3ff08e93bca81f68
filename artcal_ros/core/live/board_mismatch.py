"""Markers in view but none of the configured board: say which markers the camera sees.

A board printed with other ids (another ``first_id``, a bigger grid) or from another
dictionary gives frames full of markers that detection, rightly, ignores: without this
check the user sees "views 0" and nothing else. When a frame yields no marker of the
board, at most once every few seconds, the frame (scaled down) is searched with OpenCV's
ArucoDetector: first with the configured dictionary for ids outside the board, then with
a few common predefined dictionaries to name the one in view.

    check = BoardMismatch(board)
    check.observe(image, markers_found=len(dets))   # after every detection
    check.finding   # "" or "markers seen, none from the configured board (ids ..., ...)"
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence

import cv2
import numpy as np

from artcal_ros.core.board import Board, dictionary_by_name

# Dictionary families tried when the configured one finds nothing, largest size each
# (a smaller dictionary of a family is the first ids of the largest).
FAMILIES: tuple[str, ...] = ("DICT_4X4", "DICT_5X5", "DICT_6X6", "DICT_7X7")
SIZES = (50, 100, 250, 1000)
OTHER_DICTIONARIES: tuple[str, ...] = ("DICT_ARUCO_ORIGINAL", "DICT_APRILTAG_36h11")
CHECK_PERIOD_S = 3.0
MAX_WIDTH_PX = 1280  # the search runs on a copy scaled down to this width at most
MIN_MARKERS = 3  # fewer could be chance patterns in a cluttered scene


def _family(name: str) -> str | None:
    return next((f for f in FAMILIES if name.startswith(f + "_")), None)


def _ids_text(ids: Sequence[int]) -> str:
    ids = sorted(set(int(i) for i in ids))
    if len(ids) > 3:
        return f"{ids[0]}..{ids[-1]}, {len(ids)} markers"
    return ", ".join(str(i) for i in ids)


def _grey_small(image: np.ndarray, max_width: int) -> np.ndarray:
    img = image
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    if img.dtype != np.uint8:
        img = (img.astype(np.float32) * (255.0 / max(1.0, float(img.max())))).astype(np.uint8)
    if img.shape[1] > max_width:
        scale = max_width / img.shape[1]
        img = cv2.resize(img, (max_width, max(1, round(img.shape[0] * scale))),
                         interpolation=cv2.INTER_AREA)
    return img


class BoardMismatch:
    """Watches detection results and names the markers in view when none is the board's.

    Thread-safe: :meth:`observe` from the detection thread, :attr:`finding` from any.

    Args:
        board: the configured board.
        period_s: seconds between two searches at the most.
        clock: monotonic seconds (for tests).
    """

    def __init__(self, board: Board, *, period_s: float = CHECK_PERIOD_S,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.board = board
        self._period_s = period_s
        self._clock = clock
        self._next = 0.0
        self._lock = threading.Lock()
        self._finding = ""
        self._detectors: dict[str, cv2.aruco.ArucoDetector] = {}

    @property
    def finding(self) -> str:
        """What the last search found (empty while the board's markers are seen)."""
        with self._lock:
            return self._finding

    def observe(self, image: np.ndarray, markers_found: int) -> str:
        """Take one detection result: the image and how many board markers it gave.

        A frame with board markers clears the finding; a frame without starts a search
        if none ran in the last ``period_s``. Returns the finding now.
        """
        if markers_found > 0:
            with self._lock:
                self._finding = ""
            return ""
        now = self._clock()
        with self._lock:
            if now < self._next:
                return self._finding
            self._next = now + self._period_s
        found = self.search(image)
        with self._lock:
            self._finding = found
        return found

    def search(self, image: np.ndarray) -> str:
        """The finding for one frame: "" if no foreign markers are in view.

        Args:
            image: (H, W) uint8/uint16 or (H, W, 3) BGR uint8.
        """
        grey = _grey_small(image, MAX_WIDTH_PX)
        board = self.board
        own = board.dictionary_name
        prefix = (f"markers seen, none from the configured board (ids {board.first_id}.."
                  f"{int(board.ids[-1])}, dictionary {own})")
        ids = self._ids(grey, own)
        outside = [i for i in ids if not board.has_id(i)]
        on_board = len(ids) - len(outside)
        if len(outside) >= MIN_MARKERS or (outside and len(outside) == len(ids) >= 2):
            return f"{prefix}: the camera sees {own} ids {_ids_text(outside)}; " \
                "set board.first_id, board.cols and board.rows to the printed board"
        best, best_ids = "", list[int]()
        own_family = _family(own)
        for name in [f"{f}_1000" for f in FAMILIES if f != own_family] + \
                [d for d in OTHER_DICTIONARIES if d != own]:
            found = self._ids(grey, name)
            if len(found) > len(best_ids):
                best, best_ids = name, found
        # chance decodes of another dictionary in the board's own pattern are no finding when
        # at least as many of the board's own markers are in view
        if len(best_ids) < MIN_MARKERS or len(best_ids) <= on_board:
            return ""
        family = _family(best)
        if family is not None:  # the smallest dictionary of the family holding every id
            best = f"{family}_{next(s for s in SIZES if max(best_ids) < s)}"
        return f"{prefix}: the camera sees {best} markers (ids {_ids_text(best_ids)}); " \
            "set board.dictionary to the printed board's"

    def _ids(self, grey: np.ndarray, name: str) -> list[int]:
        detector = self._detectors.get(name)
        if detector is None:
            params = cv2.aruco.DetectorParameters()
            params.detectInvertedMarker = True  # white-on-black prints too
            detector = cv2.aruco.ArucoDetector(dictionary_by_name(name), params)
            self._detectors[name] = detector
        _, ids, _ = detector.detectMarkers(grey)
        return [] if ids is None else [int(i) for i in np.asarray(ids).ravel()]
