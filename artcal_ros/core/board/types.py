"""Board types other than the marker grid: their geometry, as plain numbers.

:class:`artcal_ros.core.board.Board` is the one board class; for ``board.type`` other than
``marker_grid`` it takes its geometry from here. Each module knows one home tool's layout:

- :mod:`.chess`: the squares of a chessboard and of a ChArUco board (OpenCV's
  ``CharucoBoard``, legacy pattern included), their inner corners and the ChArUco markers.
- :mod:`.aprilgrid`: Kalibr's AprilGrid (tag36h11, 2-bit border, Kalibr's tag and point
  numbering, the black squares where the gaps cross).
- :mod:`.circles`: OpenCV's symmetric and asymmetric circle grids (findCirclesGrid's
  patternSize and point order, the object points of OpenCV's calibration sample).
- :mod:`.text`: every board type's printed one-line description and OpenCV board object.
"""

BUILT_TYPES = ("marker_grid", "chessboard", "charuco", "aprilgrid", "circles", "acircles")
PLANNED_TYPES: tuple[str, ...] = ()
POINT_TYPES = ("chessboard", "charuco", "circles", "acircles")
