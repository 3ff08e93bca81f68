"""Camera calibration from detections: views, models, solve, uncertainty, quality, report.

:func:`calibrate` turns a list of :class:`~artcal_ros.core.detections.Detections` into a
:class:`CalibrationResult`; :mod:`.solve_run` is the collect -> select -> solve -> write path
the node and the CLI share.
"""

from artcal_ros.core.calibrate.pipeline import calibrate
from artcal_ros.core.calibrate.result import CalibrationResult

__all__ = ["CalibrationResult", "calibrate"]
