"""Marker detection: from an image to identified, sub-pixel marker corners and centers.

The pipeline (:mod:`~artcal_ros.core.detect.detector`) runs the stages front to
back: ``image`` (8-bit grey for the quad finder, linear light for everything
else) -> ``candidates`` (OpenCV's quads and ids, and ``decode`` of the quads it
rejected) -> ``edges`` (blurred-step edge fit, ``step_model``, with the lens
given or estimated by ``plumb``; side geometry in ``sides``) -> ``verify`` ->
``centers``. All of them read pixels through ``sampling``; ``patterns`` holds
what the board prints, ``lens`` the lens models.

Imports run one way, down these layers, never up or sideways (no cycles, also
none inside functions)::

    1  detector
    2  candidates
    3  decode   edges   verify
    4  plumb    centers
    5  sides
    6  step_model   lens   image   patterns
    7  sampling
"""

from artcal_ros.core.detect.detector import Detector, DetectorConfig, detect

__all__ = ["Detector", "DetectorConfig", "detect"]
