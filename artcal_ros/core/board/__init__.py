"""The calibration board: every board type, printable boards and Kalibr target files.

- :mod:`.board`: :class:`Board`, the one board class (ids, object points, polarity, the
  printed pattern) of every ``board.type``; :mod:`.types` names the types.
- :mod:`.chess`, :mod:`.aprilgrid`, :mod:`.circles`: the geometry of the types other than
  the marker grid, each in its home tool's layout; :mod:`.dictionaries` OpenCV's predefined
  ArUco dictionaries; :mod:`.text` descriptions, OpenCV board objects, the print's lines.
- :mod:`.printable` and :mod:`.paper`: printable boards (PDF, SVG, PNG) at exact scale, on
  which paper and which way round.
- :mod:`.kalibr_target`: a Kalibr target YAML as ``board.*`` parameters.
"""

from artcal_ros.core.board.board import Board, dictionary_by_name

__all__ = ["Board", "dictionary_by_name"]
