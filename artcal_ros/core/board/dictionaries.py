"""OpenCV's predefined ArUco dictionaries by name, for the board, its parameters and the CLI.

OpenCV is imported on first use: parameters are checked before the detector's imports.
"""

from __future__ import annotations


def predefined_code(name: str) -> int | None:
    """OpenCV's code of the predefined dictionary called ``name`` (``DICT_6X6_1000``), or
    None when OpenCV has none of that name."""
    import cv2

    code = getattr(cv2.aruco, name, None) if name.startswith("DICT_") else None
    return code if isinstance(code, int) else None


def predefined_names() -> list[str]:
    """Every predefined dictionary's name, sorted."""
    import cv2

    return sorted(n for n in dir(cv2.aruco) if n.startswith("DICT_"))
