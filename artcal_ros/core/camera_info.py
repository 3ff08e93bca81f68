"""camera_calibration_parsers YAML: write a calibration, read one back (ours or ROS's).

The file is the one ``camera_info_manager`` loads and ROS's ``camera_calibration``
writes for a monocular camera::

    image_width: 640
    image_height: 480
    camera_name: camera
    camera_matrix: {rows: 3, cols: 3, data: [fx, 0, cx, 0, fy, cy, 0, 0, 1]}
    distortion_model: plumb_bob
    distortion_coefficients: {rows: 1, cols: 5, data: [k1, k2, p1, p2, k3]}
    rectification_matrix: {rows: 3, cols: 3, data: [identity]}
    projection_matrix: {rows: 3, cols: 4, data: [P]}

The projection matrix is computed as ROS's ``camera_calibration`` does for a
monocular camera: the camera matrix of the undistorted image that keeps only valid
pixels (``cv2.getOptimalNewCameraMatrix`` with alpha = 0) for the pinhole models,
and K itself for ``equidistant`` (its fisheye rule with alpha = 0).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from artcal_ros.core.camera import LENS_MODELS, CameraModel, HasCamera
from artcal_ros.core.errors import ArtcalError, CalibrationError
from artcal_ros.core.files import write_text_atomic


@dataclass(frozen=True)
class CameraInfoData:
    """The content of a camera_info YAML file.

    Attributes:
        image_size: (width, height), pixels.
        camera_name: the name in the file.
        camera_matrix: (3, 3) K, pixels.
        distortion_model: ``plumb_bob`` | ``rational_polynomial`` | ``equidistant`` | other.
        dist_coeffs: (n,) distortion coefficients.
        rectification_matrix: (3, 3) R.
        projection_matrix: (3, 4) P, pixels.
    """

    image_size: tuple[int, int]
    camera_name: str
    camera_matrix: np.ndarray
    distortion_model: str
    dist_coeffs: np.ndarray
    rectification_matrix: np.ndarray
    projection_matrix: np.ndarray

    @classmethod
    def from_camera(cls, camera: CameraModel, camera_name: str = "camera") -> CameraInfoData:
        """The CameraInfo of a calibrated monocular camera: R = I, P as ROS computes it."""
        return cls(camera.size, camera_name, camera.K.copy(), camera.model, camera.dist.copy(),
                   np.eye(3), projection_matrix(camera.K, camera.dist, camera.model,
                                                camera.size))

    @property
    def camera(self) -> CameraModel:
        """The camera the file describes.

        Raises:
            ParameterError: the distortion model is not one artcal_ros knows.
        """
        return CameraModel(self.distortion_model, self.camera_matrix, self.dist_coeffs,
                           self.image_size)


def as_camera_info(calibration: CameraInfoData | CameraModel | HasCamera,
                   camera_name: str | None = None) -> CameraInfoData:
    """The CameraInfo content of a calibration: a CameraInfoData as it is (renamed if
    ``camera_name`` is given), a CameraModel, or a result with a ``camera``."""
    if isinstance(calibration, CameraInfoData):
        if camera_name is None or camera_name == calibration.camera_name:
            return calibration
        return replace(calibration, camera_name=camera_name)
    camera = calibration if isinstance(calibration, CameraModel) else calibration.camera
    return CameraInfoData.from_camera(camera, "camera" if camera_name is None else camera_name)


def projection_matrix(camera_matrix: np.ndarray, dist_coeffs: np.ndarray, model: str,
                      image_size: tuple[int, int]) -> np.ndarray:
    """The monocular projection matrix P (3, 4) that ROS's camera_calibration would write.

    Args:
        camera_matrix: (3, 3) K, pixels.
        dist_coeffs: (n,) in OpenCV order for ``model``.
        model: ``plumb_bob`` | ``rational_polynomial`` | ``equidistant``.
        image_size: (width, height), pixels.
    """
    K = np.asarray(camera_matrix, dtype=np.float64).reshape(3, 3)
    P = np.zeros((3, 4))
    if model == "equidistant":
        P[:, :3] = K
    else:
        new_K, _ = cv2.getOptimalNewCameraMatrix(K, np.asarray(dist_coeffs, np.float64),
                                                 (int(image_size[0]), int(image_size[1])), 0.0)
        P[:, :3] = new_K
    return P


def _number(v: float) -> str:
    # Shortest text that reads back to the same double; whole numbers as ROS writes them.
    return str(int(v)) if v == int(v) and abs(v) < 1e15 else repr(v)


def _matrix(rows: int, cols: int, values: np.ndarray) -> str:
    data = ", ".join(_number(float(v)) for v in np.asarray(values, np.float64).ravel())
    return f"  rows: {rows}\n  cols: {cols}\n  data: [{data}]\n"


def camera_info_yaml(calibration: CameraInfoData | CameraModel | HasCamera,
                     camera_name: str | None = None) -> str:
    """The YAML text of a calibration (see :func:`as_camera_info` for what it takes).

    Raises:
        CalibrationError: the calibration holds non-finite numbers.
    """
    info = as_camera_info(calibration, camera_name)
    K = np.asarray(info.camera_matrix, dtype=np.float64).reshape(3, 3)
    D: np.ndarray = np.asarray(info.dist_coeffs, dtype=np.float64).ravel()
    model = info.distortion_model
    w, h = (int(info.image_size[0]), int(info.image_size[1]))
    if model in LENS_MODELS and len(D) < LENS_MODELS[model].n_dist:
        D = np.concatenate([D, np.zeros(LENS_MODELS[model].n_dist - len(D))])
    R = np.asarray(info.rectification_matrix, np.float64).reshape(3, 3)
    P = np.asarray(info.projection_matrix, np.float64).reshape(3, 4)
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(D)) and np.all(np.isfinite(P))):
        raise CalibrationError("the calibration holds non-finite numbers; nothing was written")
    name = str(info.camera_name)
    if not name or any(c in name for c in ":#\n{}[],&*!|>'\"%@`"):
        name = yaml.safe_dump(name, default_style='"').strip()
    return (f"image_width: {w}\nimage_height: {h}\ncamera_name: {name}\n"
            f"camera_matrix:\n{_matrix(3, 3, K.ravel())}"
            f"distortion_model: {model}\n"
            f"distortion_coefficients:\n{_matrix(1, len(D), D)}"
            f"rectification_matrix:\n{_matrix(3, 3, R.ravel())}"
            f"projection_matrix:\n{_matrix(3, 4, P.ravel())}")


def write_camera_info_yaml(path: str | os.PathLike[str],
                           calibration: CameraInfoData | CameraModel | HasCamera,
                           camera_name: str | None = None) -> Path:
    """Write a calibration as camera_calibration_parsers YAML, atomically.

    The text is built and checked first, written to a temporary file in the same
    directory, flushed to disk and renamed over ``path``: a reader never sees a partial
    file, a kill at any moment leaves the old file or the new one (and at worst a stray
    ``.<name>.*.tmp`` beside it), and a failure (no permission, a full disk) leaves any
    existing file untouched and names the path and the reason.

    Args:
        path: the file to write (parent directories are created).
        calibration: a CalibrationResult, a CameraModel or a CameraInfoData.
        camera_name: the ``camera_name`` field (default: the CameraInfoData's, else
            ``camera``).

    Returns:
        The path written.

    Raises:
        CalibrationError: the result holds non-finite numbers (nothing written).
        ArtcalError: the file cannot be written.
    """
    return write_text_atomic(path, camera_info_yaml(calibration, camera_name))


def _read_matrix(doc: dict[str, Any], key: str, path: Path, shape: tuple[int, int] | None,
                 ) -> np.ndarray:
    block = doc.get(key)
    if not isinstance(block, dict) or "data" not in block:
        raise ArtcalError(f"{path}: '{key}' is missing or has no 'data'")
    try:
        data = np.asarray(block["data"], dtype=np.float64).ravel()
        rows, cols = int(block.get("rows", 1)), int(block.get("cols", len(data)))
    except (TypeError, ValueError):
        raise ArtcalError(f"{path}: '{key}' holds something other than numbers") from None
    if rows * cols != len(data) or (shape is not None and (rows, cols) != shape):
        want = f" (expected {shape[0]}x{shape[1]})" if shape else ""
        raise ArtcalError(f"{path}: '{key}' is {rows}x{cols} with {len(data)} values{want}")
    return data.reshape(rows, cols)


def read_camera_info_yaml(path: str | os.PathLike[str]) -> CameraInfoData:
    """Read a camera_calibration_parsers YAML file (ours, or any ROS tool's).

    The legacy key ``camera_model`` is accepted for ``distortion_model``.

    Raises:
        ArtcalError: the file is missing, not YAML, or lacks a field (named).
    """
    p = Path(path).expanduser()
    try:
        doc = yaml.safe_load(p.read_text())
    except OSError as e:
        raise ArtcalError(f"cannot read {p}: {e.strerror}") from None
    except yaml.YAMLError as e:
        raise ArtcalError(f"{p} is not valid YAML: {e}") from None
    if not isinstance(doc, dict):
        raise ArtcalError(f"{p}: expected a mapping of camera_info fields")
    try:
        w, h = int(doc["image_width"]), int(doc["image_height"])
    except (KeyError, TypeError, ValueError):
        raise ArtcalError(f"{p}: 'image_width' and 'image_height' must be integers") from None
    model = doc.get("distortion_model", doc.get("camera_model"))
    if not isinstance(model, str):
        raise ArtcalError(f"{p}: 'distortion_model' is missing")
    K = _read_matrix(doc, "camera_matrix", p, (3, 3))
    D = _read_matrix(doc, "distortion_coefficients", p, None).ravel()
    R = (_read_matrix(doc, "rectification_matrix", p, (3, 3))
         if "rectification_matrix" in doc else np.eye(3))
    P = (_read_matrix(doc, "projection_matrix", p, (3, 4))
         if "projection_matrix" in doc else projection_matrix(K, D, model, (w, h)))
    return CameraInfoData((w, h), str(doc.get("camera_name", "")), K, model, D, R, P)
