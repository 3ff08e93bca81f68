"""Kalibr's AprilGrid: tag36h11 tags with a 2-bit black border, and Kalibr's numbering.

Kalibr (``kalibr_create_target_pdf``, ``GridCalibrationTargetAprilgrid``) prints ``tagCols``
x ``tagRows`` tags of side ``tagSize`` (border included), ``tagSize * tagSpacing`` apart, and
a black square of that gap's side at every corner where four gaps meet (also around the
grid's outside), so each tag corner is an X-corner. Tag 0 is at the bottom-left of the print,
ids run left to right, then upwards. Each tag is 10 modules wide: 2 of black border, 6 of
code. The code is the tag36h11 word read row-major from the top-left module, most
significant bit first, 1 = white: OpenCV's ``DICT_APRILTAG_36h11`` marker image turned by
180 degrees.

Kalibr's points are the tag corners: ``2 * tagCols`` x ``2 * tagRows`` of them, numbered
row-major from the bottom-left (y up on the print); tag ``k``'s corners are, in Kalibr's
order, bottom-left, bottom-right, top-right, top-left on the print.

The pipeline here sees a tag as a marker of 8 x 8 code bits inside a 1-module border: the
inner ring of the 2-bit border becomes code bits that are always black. Everything that
reads "bits + 2 modules per marker" then holds unchanged.
"""

from __future__ import annotations

import cv2
import numpy as np

TAG_BITS = 6        # tag36h11: 6 x 6 code bits
PIPELINE_BITS = 8   # code bits as the marker pipeline sees them (the black inner ring added)
# the parameter's default (DICT_6X6_1000) means "not given" on an aprilgrid
ACCEPTED_DICTIONARIES = ("tag36h11", "DICT_APRILTAG_36h11", "DICT_6X6_1000")


def aprilgrid_complaint(dictionary: str, polarity: str, first_id: int) -> str | None:
    """What is wrong with these parameters for an aprilgrid (None when they fit), naming the
    parameter; node, CLI and :class:`~artcal_ros.core.board.Board` share it."""
    if dictionary not in ACCEPTED_DICTIONARIES:
        return (f"parameter 'board.dictionary': {dictionary!r}; an aprilgrid prints tag36h11: "
                "use tag36h11 (or leave it unset)")
    if polarity != "black":
        return (f"parameter 'board.polarity': {polarity!r}; an aprilgrid prints black tags on "
                "white: use black")
    if first_id != 0:
        return (f"parameter 'board.first_id': {first_id}; Kalibr's aprilgrid numbers its tags "
                "from 0: use 0")
    return None


def describe(cols: int, rows: int, tag_size: float, spacing_m: float, size: str) -> str:
    """The line printed on an aprilgrid's margin, in Kalibr's terms."""
    return (f"artcal aprilgrid (Kalibr) {cols}x{rows} tag36h11 tagSize {tag_size * 1000:g} mm "
            f"tagSpacing {spacing_m / tag_size:g} {size}")


def aprilgrid_dictionary(n_tags: int) -> cv2.aruco.Dictionary:
    """The first ``n_tags`` tag36h11 codes as an 8 x 8-bit OpenCV dictionary, as printed by
    Kalibr (upright on the board: the detector's top-left corner is the print's top-left).

    The Hamming distance between codes is tag36h11's (11), the added ring never differs.
    """
    source = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    n = min(int(n_tags), int(source.bytesList.shape[0]))
    rows = []
    for tag_id in range(n):
        img = cv2.aruco.generateImageMarker(source, tag_id, TAG_BITS + 2, borderBits=1)
        code = np.rot90(img[1:-1, 1:-1] > 127, 2)
        bits = np.zeros((PIPELINE_BITS, PIPELINE_BITS), np.uint8)
        bits[1:-1, 1:-1] = code
        rows.append(cv2.aruco.Dictionary.getByteListFromBits(bits))
    return cv2.aruco.Dictionary(np.concatenate(rows, axis=0), PIPELINE_BITS,
                                int(source.maxCorrectionBits))


def point_cells(point_ids: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """(M, 2) int64 (row, col) of Kalibr's points in the 2 rows x 2 cols grid, row 0 at the
    top."""
    p = np.asarray(point_ids, dtype=np.int64).reshape(-1)
    return np.stack([2 * rows - 1 - p // (2 * cols), p % (2 * cols)], axis=1)


def tag_cells(tag_ids: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """(N, 2) int64 (row, col) of tags in the board frame (row 0 at the top): Kalibr's tag
    ``k`` sits in tag row ``k // cols`` counted from the bottom."""
    k = np.asarray(tag_ids, dtype=np.int64).reshape(-1)
    return np.stack([rows - 1 - k // cols, k % cols], axis=1)


def kalibr_corner_ids(tag_ids: np.ndarray, cols: int) -> np.ndarray:
    """(N, 4) int64: Kalibr's point id of each tag's corners, listed TL, TR, BR, BL on the
    print (this package's marker corner order)."""
    k = np.asarray(tag_ids, dtype=np.int64).reshape(-1)
    width = 2 * cols
    base = (k // cols) * 2 * width + (k % cols) * 2   # the tag's bottom-left point
    return np.stack([base + width, base + width + 1, base + 1, base], axis=1)


def kalibr_points(point_ids: np.ndarray, cols: int, rows: int, tag_size: float,
                  spacing_m: float) -> np.ndarray:
    """(M, 3) float64, metres: Kalibr's points in this package's board frame (origin at the
    top-left tag's outer top-left corner, y down), i.e. Kalibr's (x, y) as (x, H - y)."""
    p = np.asarray(point_ids, dtype=np.int64).reshape(-1)
    width = 2 * cols
    r, c = p // width, p % width
    pitch = tag_size + spacing_m
    height = rows * pitch - spacing_m
    out = np.zeros((len(p), 3))
    out[:, 0] = (c // 2) * pitch + (c % 2) * tag_size
    out[:, 1] = height - ((r // 2) * pitch + (r % 2) * tag_size)
    return out


def in_corner_square(x: np.ndarray, y: np.ndarray, cols: int, rows: int, tag_size: float,
                     spacing_m: float) -> np.ndarray:
    """Whether board points (metres, board frame) lie in one of the black squares Kalibr
    prints where the gaps between tags cross (and around the grid's outside)."""
    pitch = tag_size + spacing_m

    def in_gap(t: np.ndarray, count: int) -> np.ndarray:
        # gap j spans [j * pitch - spacing, j * pitch), j = 0 .. count
        j = np.floor((t + spacing_m) / pitch)
        return (j >= 0) & (j <= count) & (t + spacing_m - j * pitch < spacing_m)

    return in_gap(x, cols) & in_gap(y, rows)
