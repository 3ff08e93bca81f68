"""Why the configured board is not found: what the images show instead, and the likely fix.

"0 usable views" says nothing about the cause; the usual causes are the board's
description, not the views: a chessboard counted in squares instead of inner corners, the
wrong dictionary, a ChArUco marker length that does not fit the squares. Run only when
the board is found in under half of the images, on a few of those where it is not
(each search costs about a tenth of a second per image):

- a chessboard of another size: OpenCV's sector-based finder with ``CALIB_CB_LARGER``
  reports the whole grid of inner corners it sees; the sizes it names are then confirmed
  with the detector's own grid finder (:func:`~artcal_ros.core.detect.chessboard.find_grid`);
- markers of another dictionary, or of the board's dictionary with ids not on the board
  (:class:`~artcal_ros.core.live.board_mismatch.BoardMismatch`);
- ChArUco: the markers' side over the square side, measured in the board plane (each
  marker's corners mapped through the homography of the marker centres, which sit at the
  square centres whatever the marker length), against the configured ratio.

::

    search = BoardSearch.of(dets, board, points="centers", images=sample)
    if search.partial:
        print(search.text())   # "the board (...) is found in only 6 of 13 images; ..."
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.calibrate.views import view_points, view_problem
from artcal_ros.core.detect.chessboard import find_grid
from artcal_ros.core.detect.image import to_gray, to_gray8
from artcal_ros.core.detections import Detections
from artcal_ros.core.live.board_mismatch import BoardMismatch

__all__ = ["MAX_IMAGES", "BoardSearch", "board_found", "board_name", "diagnose"]

MAX_IMAGES = 4  # images searched for what else is in view
RATIO_TOLERANCE = 0.1  # a measured marker/square ratio this far (relative) from the configured


def board_name(board: Board) -> str:
    """The configured board in a few words, for messages."""
    t = board.board_type
    if t == "chessboard":
        return f"chessboard of {board.cols}x{board.rows} inner corners"
    if t == "charuco":
        return (f"ChArUco board of {board.cols}x{board.rows} squares, "
                f"{board.dictionary_name}, marker/square {_ratio(board):.2f}")
    if t == "aprilgrid":
        return f"AprilGrid of {board.cols}x{board.rows} tags"
    if t in ("circles", "acircles"):
        kind = "asymmetric " if t == "acircles" else ""
        return f"{kind}circle grid of {board.cols}x{board.rows} circles"
    return f"marker grid of {board.cols}x{board.rows} {board.dictionary_name} markers"


def _ratio(board: Board) -> float:
    return board.marker_length / board.square_length


def board_found(det: Detections, board: Board, points: str = "centers") -> bool:
    """Whether the image gave a view of the board the solve can use."""
    return view_problem(view_points(det, board, points, 0), board) is None


def _oriented(size: tuple[int, int], board: Board) -> tuple[int, int]:
    """A grid size (either way round) turned the way the board is configured."""
    a, b = size
    return (a, b) if (a >= b) == (board.cols >= board.rows) else (b, a)


def chessboard_finding(grays: Sequence[np.ndarray], board: Board, *,
                       markers_seen: bool = False) -> str:
    """A chessboard of another size than the configured one, and the fix; "" if none.

    Args:
        grays: (H, W) uint8 images where the board is not found.
        markers_seen: markers of the board's dictionary are in view too (a chessboard with
            them in its squares is a ChArUco board).
    """
    votes: Counter[tuple[int, int]] = Counter()
    for gray in grays:
        ok, corners, meta = cv2.findChessboardCornersSBWithMeta(gray, (3, 3),
                                                               cv2.CALIB_CB_LARGER)
        if ok and meta is not None and corners is not None and len(corners) == meta.size:
            votes[_oriented((int(meta.shape[1]), int(meta.shape[0])), board)] += 1
    if board.board_type == "charuco":
        configured = (board.cols - 1, board.rows - 1)
    elif board.board_type == "chessboard":
        configured = (board.cols, board.rows)
    else:
        configured = (0, 0)
    for size, _ in votes.most_common(2):
        if size == configured or min(size) < 2:
            continue
        found = sum(1 for g in grays if find_grid(g, *size) is not None)
        if not found:
            continue
        c, r = size
        seen = f"found a chessboard of {c}x{r} inner corners in {found} of {len(grays)} " \
            "images checked"
        if board.board_type == "chessboard":
            return f"{seen}: use --size {c}x{r} (board.cols {c}, board.rows {r})"
        if board.board_type == "charuco":
            return (f"{seen}, a ChArUco board of {c + 1}x{r + 1} squares: set board.cols "
                    f"{c + 1} and board.rows {r + 1} (ChArUco counts squares, not corners)")
        if markers_seen:
            return (f"{seen}, with markers in its squares: a ChArUco board of {c + 1}x{r + 1} "
                    f"squares? set board.type charuco, board.cols {c + 1}, board.rows {r + 1}")
        return f"{seen}: for a chessboard use --size {c}x{r} --square METRES"
    return ""


def _board_markers(gray: np.ndarray, board: Board) -> tuple[np.ndarray, np.ndarray]:
    """(ids (N,), corners (N, 4, 2) px) of the board's markers OpenCV's ArucoDetector finds
    with the board's dictionary."""
    params = cv2.aruco.DetectorParameters()
    # the contour corners lie about a pixel inside the marker's edge: refined, they sit on it
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    corners, ids, _ = cv2.aruco.ArucoDetector(board.dictionary, params).detectMarkers(gray)
    if ids is None:
        return np.zeros(0, np.int64), np.zeros((0, 4, 2))
    ids = np.asarray(ids, np.int64).ravel()
    keep = board.has_ids(ids)
    return ids[keep], np.asarray(corners, np.float64).reshape(-1, 4, 2)[keep]


def charuco_ratio_finding(grays: Sequence[np.ndarray], board: Board) -> str:
    """ChArUco markers whose measured size over the square does not fit the configured
    ``board.marker_length / board.square_length``, and the fix; "" if they fit."""
    if board.board_type != "charuco":
        return ""
    ratios: list[float] = []
    for gray in grays:
        ids, quads = _board_markers(gray, board)
        if len(ids) < 4:
            continue
        centers_m = board.object_centers(ids)[:, :2]
        H, _ = cv2.findHomography(quads.mean(axis=1), centers_m)
        if H is None:
            continue
        flat = cv2.perspectiveTransform(quads.reshape(-1, 1, 2), H).reshape(-1, 4, 2)
        sides = np.linalg.norm(flat - np.roll(flat, -1, axis=1), axis=2)
        ratios.extend((np.median(sides, axis=1) / board.square_length).tolist())
    if len(ratios) < 4:
        return ""
    measured = float(np.median(ratios))
    configured = _ratio(board)
    if abs(measured / configured - 1.0) <= RATIO_TOLERANCE:
        return ""
    return (f"the markers measure about {measured:.2f} of the square side, the configuration "
            f"says {configured:.2f} (board.marker_length {board.marker_length:g} / "
            f"board.square_length {board.square_length:g}): measure a marker on the print "
            f"and set board.marker_length (about {measured * board.square_length:.3g} m with "
            "this board.square_length)")


def marker_finding(images: Sequence[np.ndarray], board: Board) -> str:
    """Markers of another dictionary, or ids not on the board, and the fix; "" if none."""
    if board.n_markers == 0:
        return ""
    search = BoardMismatch(board)
    for image in images:
        found = search.search(image)
        if found:
            return found
    return ""


def diagnose(images: Sequence[np.ndarray], board: Board) -> list[str]:
    """What the images show instead of the board, each with the likely fix.

    Args:
        images: a few images where the board is not found, (H, W) uint8/uint16 or
            (H, W, 3) BGR uint8.
    """
    images = list(images)[:MAX_IMAGES]
    grays = [to_gray8(to_gray(im)) for im in images]
    out = [marker_finding(images, board), charuco_ratio_finding(grays, board)]
    if board.circles is None:
        seen = board.n_markers > 0 and any(len(_board_markers(g, board)[0]) >= 3
                                           for g in grays)
        out.append(chessboard_finding(grays, board, markers_seen=seen))
    return [f for f in out if f]


@dataclass(frozen=True)
class BoardSearch:
    """Where the configured board is found, and what was seen where it is not.

    Attributes:
        board: the configured board's name (:func:`board_name`).
        images: images given.
        found: images that gave a usable view of the board.
        checked: images searched for something else.
        findings: what was seen instead, each with the likely fix.
    """

    board: str
    images: int
    found: int
    checked: int
    findings: tuple[str, ...]

    @property
    def partial(self) -> bool:
        """The board is found in under half of the images."""
        return 2 * self.found < self.images

    @classmethod
    def of(cls, dets: Sequence[Detections], board: Board, *, points: str,
           images: Sequence[tuple[int, np.ndarray]]) -> BoardSearch:
        """Count where the board is found; search a few others when under half.

        Args:
            dets: one per image given.
            images: (position in ``dets``, image) of the images kept for the search.
        """
        found = [board_found(d, board, points) for d in dets]
        n_found = sum(found)
        if 2 * n_found >= len(dets):
            return cls(board_name(board), len(dets), n_found, 0, ())
        missing = [im for k, im in images if 0 <= k < len(found) and not found[k]]
        missing = missing[:MAX_IMAGES]
        return cls(board_name(board), len(dets), n_found, len(missing),
                   tuple(diagnose(missing, board)))

    def text(self) -> str:
        """One line: where the board is found and, when in under half, what instead."""
        where = (f"the board ({self.board}) is found in {'only ' if self.found else ''}"
                 f"{self.found} of {self.images} images")
        if not self.partial:
            return where
        if self.findings:
            others = "in the others" if self.found else "seen instead"
            return f"{where}; {others}: {'; '.join(self.findings)}"
        return (f"{where}; nothing else recognised in the {self.checked} others checked: "
                "check the board parameters, focus and light")

    def as_dict(self) -> dict[str, object]:
        """JSON-ready: ``images``, ``found``, ``checked``, ``findings``."""
        return {"board": self.board, "images": self.images, "found": self.found,
                "checked": self.checked, "findings": list(self.findings)}
