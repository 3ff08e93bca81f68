"""Run a calibration off the executor, write the YAML, and phrase the answer (ROS-free glue)."""

from __future__ import annotations

import threading
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.coverage import Readiness
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError
from artcal_ros.core.params import output_path

# Solve threads started (the node waits for live ones at shutdown, see busy_threads).
SOLVE_THREADS: list[threading.Thread] = []


def busy_threads() -> list[threading.Thread]:
    """Solve threads still running."""
    return [t for t in SOLVE_THREADS if t.is_alive()]


@dataclass(frozen=True)
class SolveOutcome:
    """What ``~/calibrate`` answers: success, a one-line message, and the result if any."""

    success: bool
    message: str
    result: Any = None


def summary_line(result: Any) -> str:
    """RMS, fx, fy, cx, cy and views used, on one line."""
    K = np.asarray(result.camera_matrix)
    used = result.views_used
    n_used = used if isinstance(used, int) else len(used)
    return (f"RMS {float(result.reprojection_rms_px):.3f} px, fx {K[0, 0]:.2f} fy {K[1, 1]:.2f} "
            f"cx {K[0, 2]:.2f} cy {K[1, 2]:.2f}, {n_used} views used ({result.model})")


class CancelledError(Exception):
    """Raised from the solve's progress callback to end it early (node shutting down)."""


def _solve(views: Sequence[Detections], board: Board, image_size: tuple[int, int],
           params: Mapping[str, Any], stopping: threading.Event) -> Any:
    from artcal_ros.core.calibrate.pipeline import calibrate
    from artcal_ros.core.camera_info import write_camera_info_yaml

    def progress(_stage: str) -> None:
        if stopping.is_set():
            raise CancelledError

    result = calibrate(list(views), board, image_size=image_size,
                       model=str(params["camera_model"]), points=str(params["points"]),
                       max_views=int(params["max_views"]), progress=progress)
    path = output_path(params)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_camera_info_yaml(path, result, camera_name=str(params["camera_name"]))
    return result


def run_solve(views: Sequence[Detections], board: Board, image_size: tuple[int, int],
              params: Mapping[str, Any], readiness: Readiness, *,
              stopping: threading.Event) -> SolveOutcome:
    """Calibrate from ``views`` on a daemon thread, waiting for it unless ``stopping`` is set.

    On shutdown (``stopping`` set) the wait ends at once and the solve stops at its next
    stage; the node waits briefly for it (see :func:`busy_threads`).

    Args:
        views: the kept views (all of one image size).
        board: the board.
        image_size: (width, height), pixels.
        params: validated parameters (camera_model, points, max_views, output_file, ...).
        readiness: the collection's state, mentioned in the answer when not ideal.
        stopping: set on shutdown; the wait then ends with success=false.
    """
    box: dict[str, Any] = {}
    done = threading.Event()

    def work() -> None:
        try:
            box["value"] = _solve(views, board, image_size, params, stopping)
        except CancelledError:
            box["error"] = "cancelled"
        except ArtcalError as e:
            box["error"] = str(e)
        except OSError as e:
            box["error"] = f"could not write {output_path(params)}: {e.strerror or e}"
        except Exception as e:
            box["error"] = f"internal error: {e!r}"
        finally:
            done.set()

    thread = threading.Thread(target=work, name="solve", daemon=True)
    thread.start()
    SOLVE_THREADS.append(thread)
    while not done.wait(0.1):
        if stopping.is_set():
            return SolveOutcome(False, "shutting down; calibration abandoned")
    if "error" in box:
        return SolveOutcome(False, f"calibration failed: {box['error']}")
    result = box["value"]
    message = f"{summary_line(result)}; wrote {output_path(params)}"
    warnings = list(getattr(result, "warnings", ()) or ())
    if warnings:
        message += f"; warnings: {'; '.join(str(w) for w in warnings)}"
    if not readiness.ready:
        message += f"; note, still missing: {'; '.join(readiness.missing)}"
    return SolveOutcome(True, message, result)
