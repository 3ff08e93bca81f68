"""Board types other than the marker grid: their geometry, as plain numbers.

:class:`artcal_ros.core.board.Board` is the one board class; for ``board.type`` other than
``marker_grid`` it takes its geometry from here. Each module knows one home tool's layout:

- :mod:`.chess`: the squares of a chessboard and of a ChArUco board (OpenCV's
  ``CharucoBoard``, legacy pattern included), their inner corners and the ChArUco markers.
"""

BUILT_TYPES = ("marker_grid", "chessboard", "charuco")
PLANNED_TYPES = ("aprilgrid", "circles", "acircles")
POINT_TYPES = ("chessboard", "charuco")
