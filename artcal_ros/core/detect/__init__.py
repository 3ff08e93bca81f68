"""Marker detection: from an image to identified, sub-pixel marker corners and centers.

The pipeline runs front to back, and each stage imports only the stages below it:
``image`` (grey and linear light) -> ``candidates`` (quads and ids) -> ``decode`` ->
``edges`` (blurred-step edge fit, with ``step_model`` and ``lens``) -> ``verify`` ->
``centers``, all reading pixels through ``sampling``. :class:`Detector` ties them together.
"""

from artcal_ros.core.detect.detector import Detector, DetectorConfig, detect

__all__ = ["Detector", "DetectorConfig", "detect"]
