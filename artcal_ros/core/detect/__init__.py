"""Detection: from an image to identified, sub-pixel marker corners and centers, and the
saddle points of chessboard and ChArUco boards.

The pipeline (:mod:`~artcal_ros.core.detect.detector`) runs the stages front to
back: ``image`` (8-bit grey for the quad finder, linear light for everything
else) -> ``candidates`` (OpenCV's quads and ids, and ``decode`` of the quads it
rejected) -> ``edges`` (blurred-step edge fit, ``step_model``, with the lens
given or estimated by ``plumb``, how far its bend is trusted in ``bends``; side
geometry in ``sides``; the pixels across
the sides read by ``profiles``; ``light`` the light's slope along each side, from the
frame's light field) -> ``verify`` -> ``centers``. All of them read
pixels through ``sampling``; ``patterns`` holds what the board prints, ``lens``
the lens models, ``tone`` the tone curve (estimated from the edge fits), ``edge_shift``
the per-view edge shift removed from the corners; ``exposure`` says whether a frame is
clipped or partly saturated, ``grid_search`` looks for the markers of a clipped frame
where the board's layout puts them, and ``rim`` reads again, through the lens, the quads a
strong lens distorts too much to decode. The hot loops are numba
kernels (compiled on first use and cached on disk); ``linalg`` has their small
solves, ``workers`` the threads the model fit runs on (``ARTCAL_THREADS``, default 2).
``frames`` detects a recording's frames on worker processes (offline, every frame);
``stream_predict`` gives a Detector fed consecutive frames the markers the frames before
place, so the quad finder searches only the rest of the image.
A chessboard goes to ``chessboard``
(OpenCV's grid finders, ids from the squares' colours); a ChArUco board runs the marker
pipeline, then ``charuco`` places its corners from the markers. An AprilGrid (Kalibr) runs the
marker pipeline as it is: its board's dictionary sees each tag's 2-bit border as a 1-bit
border around 8 x 8 code bits (:mod:`artcal_ros.core.board.aprilgrid`). Both refine their
corners with ``saddle``, a fit of the blurred X-corner model in linear light. Circle grids go
to ``circles`` (``circle_grid`` finds, orders and checks the grid).

Imports run one way, down these layers, never up or sideways (no cycles, also
none inside functions); every module of the package is in one layer, and
test/unit/test_layout.py checks both::

    0  frames
    1  detector
    2  stream_predict
    3  candidates   grid_search   rim   chessboard   charuco   circles
    4  decode   edges   exposure   verify   circle_grid
    5  plumb    centers   profiles   bends
    6  sides    light
    7  step_model   saddle   lens   image   patterns   tone   edge_shift
    8  sampling   linalg   workers   config
"""

from artcal_ros.core.detect.detector import Detector, DetectorConfig, detect

__all__ = ["Detector", "DetectorConfig", "detect"]
