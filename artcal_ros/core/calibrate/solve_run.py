"""The solve run the node and the CLI share: views -> select -> solve -> write -> summary.

ROS-free. The CLI collects views with :func:`detect_views` from image files or a bag, the
node with its :class:`~artcal_ros.core.live.coverage.ViewCollector` from a live stream; both
then call :func:`solve_views` (the solve options come from the flat parameters through
:func:`calibrate_kwargs`, so node and CLI read the same ``calibrate.*`` names) and phrase
the result with :func:`solve_summary`. The node runs it off the executor thread on its
:class:`SolveWorker` (the result a :class:`concurrent.futures.Future`) through
:func:`run_solve`.

::

    run = solve_views(dets, board, size, params)   # calibrates, writes the YAML
    print(solve_summary(run, long=True))
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import Future, wait
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detections import Detections
from artcal_ros.core.errors import ArtcalError, ImageFormatError, ParameterError
from artcal_ros.core.live.coverage import Readiness
from artcal_ros.core.params import output_path

if TYPE_CHECKING:
    from artcal_ros.core.calibrate.result import CalibrationResult
    from artcal_ros.core.detect import Detector

T = TypeVar("T")


class OutputError(ArtcalError):
    """Calibrated, but the calibration file could not be written (the message names the
    path and the reason; ``result`` is the calibration)."""

    def __init__(self, message: str, result: CalibrationResult) -> None:
        super().__init__(message)
        self.result = result


@dataclass(frozen=True)
class SolveOutcome:
    """What ``~/calibrate`` answers: success, a one-line message, and the result if any."""

    success: bool
    message: str
    result: Any = None


@dataclass(frozen=True)
class SolveRun:
    """A finished solve run.

    Attributes:
        result: the calibration.
        path: the camera_calibration_parsers YAML written.
        seconds: wall time of the solve and the write, seconds.
    """

    result: CalibrationResult
    path: Path
    seconds: float


def calibrate_kwargs(params: Mapping[str, Any]) -> dict[str, Any]:
    """The keyword arguments of :func:`~artcal_ros.core.calibrate.calibrate` from the flat
    parameters (``camera_model``, ``points``, ``max_views`` and the ``calibrate.*`` options).

    Args:
        params: validated parameters (:func:`artcal_ros.core.params.load_params`).
    """
    return {"model": str(params["camera_model"]), "points": str(params["points"]),
            "max_views": int(params["max_views"]),
            "k_coefficients": int(params["calibrate.k_coefficients"]),
            "fix_principal_point": bool(params["calibrate.fix_principal_point"]),
            "fix_aspect_ratio": bool(params["calibrate.fix_aspect_ratio"]),
            "zero_tangent_dist": bool(params["calibrate.zero_tangent_dist"])}


def detect_views(frames: Iterable[tuple[str, np.ndarray]], board: Board, *,
                 detector: Detector | None = None
                 ) -> tuple[list[Detections], tuple[int, int]]:
    """Collect views: detect the markers in every frame of one camera.

    Args:
        frames: (source name, image) pairs; images (H, W) uint8/uint16 or (H, W, 3) BGR.
        board: the board.
        detector: the detector to use (its tone curve and lens estimate are then the
            frames'); a default one without.

    Returns:
        (one Detections per frame, (width, height) pixels).

    Raises:
        ImageFormatError: the frames differ in size.
        ParameterError: there are no frames.
    """
    from artcal_ros.core.detect import Detector

    detector = detector if detector is not None else Detector(board)
    dets: list[Detections] = []
    size: tuple[int, int] | None = None
    for source, image in frames:
        h, w = image.shape[:2]
        if size is None:
            size = (w, h)
        elif size != (w, h):
            raise ImageFormatError(f"{source} is {w}x{h} but the first image is "
                                   f"{size[0]}x{size[1]}; calibrate one camera at a time")
        dets.append(detector.detect(image, source=source))
    if size is None:
        raise ParameterError("no images: give image files or --bag BAG")
    return dets, size


def solve_views(views: Sequence[Detections], board: Board, image_size: tuple[int, int],
                  params: Mapping[str, Any], *, output: str | Path | None = None,
                  max_views: int | None = None, accept_weak: bool = False,
                  progress: Callable[[str], None] | None = None) -> SolveRun:
    """Select views, solve with the parameters' options and write the calibration YAML.

    Args:
        views: the collected views (all of one image size).
        board: the board.
        image_size: (width, height), pixels.
        params: validated parameters (camera_model, points, calibrate.*, max_views,
            camera_name, output_file).
        output: the YAML to write (default: :func:`~artcal_ros.core.params.output_path`).
        max_views: solve from at most this many views (default: ``max_views``).
        accept_weak: solve a set the view checks refuse when a solve is possible at all
            (:func:`~artcal_ros.core.calibrate.calibrate`'s ``accept_weak``).
        progress: called with a short message at each stage; may raise to stop.

    Raises:
        CalibrationError: the views cannot support a solve; nothing is written (an
            existing file is left as it was).
        OutputError: calibrated, but the file cannot be written (the result is in it).
    """
    from artcal_ros.core.calibrate.pipeline import calibrate
    from artcal_ros.core.camera_info import write_camera_info_yaml

    start = time.monotonic()
    kwargs = calibrate_kwargs(params)
    if max_views is not None:
        kwargs["max_views"] = int(max_views)
    result = calibrate(list(views), board, image_size=image_size, progress=progress,
                       accept_weak=accept_weak, **kwargs)
    path = Path(output).expanduser() if output is not None else output_path(params)
    try:
        write_camera_info_yaml(path, result, camera_name=str(params["camera_name"]))
    except ArtcalError as e:
        raise OutputError(str(e), result) from None
    return SolveRun(result, path, time.monotonic() - start)


def solve_summary(run: SolveRun, *, long: bool = False,
                    readiness: Readiness | None = None) -> str:
    """The one summary of a solve run: the result's own (short or long, see
    :meth:`CalibrationResult.summary`), the file written and, for the node, what the
    collection still lacks."""
    text = run.result.summary(long=long)
    if long:
        text += f"\nwrote {run.path} ({run.seconds:.1f} s)"
    else:
        text += f"; wrote {run.path}"
    if readiness is not None and not readiness.ready:
        text += ("\n" if long else "; ") + f"note, still missing: {'; '.join(readiness.missing)}"
    return text


class CancelledError(Exception):
    """Raised from the solve's progress callback to end it early (node shutting down)."""


@dataclass(frozen=True)
class _SolveJob:
    future: Future[Any]
    solve: Callable[[], Any]


class SolveWorker:
    """Runs solves one at a time on one thread, named "solve", that it starts and joins.

    :meth:`submit` returns the run as a :class:`concurrent.futures.Future`; :meth:`close`
    ends a solve in progress at its next stage and joins the thread. Also a context
    manager (closed on exit).
    """

    def __init__(self, *, name: str = "solve") -> None:
        self._jobs: queue.SimpleQueue[_SolveJob | None] = queue.SimpleQueue()
        self._cancel = threading.Event()
        self._lock = threading.Lock()  # submit against close: no job is queued after the end
        self._closed = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def submit(self, views: Sequence[Detections], board: Board, image_size: tuple[int, int],
               params: Mapping[str, Any], *, cancel: threading.Event | None = None
               ) -> Future[SolveRun]:
        """Queue :func:`solve_views` of these views; its run (or its exception) comes back
        in the future. ``cancel``: once set, the solve ends at its next stage with
        :class:`CancelledError` (so does :meth:`close`)."""
        def progress(_stage: str) -> None:
            if self._cancel.is_set() or (cancel is not None and cancel.is_set()):
                raise CancelledError

        views, params = list(views), dict(params)  # the caller's may change meanwhile
        future: Future[SolveRun] = Future()
        with self._lock:
            if self._closed:
                future.set_exception(CancelledError())
                return future
            self._jobs.put(_SolveJob(future, lambda: solve_views(
                views, board, image_size, params, progress=progress)))
        return future

    def submit_task(self, task: Callable[[], T]) -> Future[T]:
        """Queue other work of a solve's (its report) behind the solves queued now, on the
        same thread; its return value (or exception) comes back in the future."""
        future: Future[T] = Future()
        with self._lock:
            if self._closed:
                future.set_exception(CancelledError())
                return future
            self._jobs.put(_SolveJob(future, task))
        return future

    def _run(self) -> None:
        while (job := self._jobs.get()) is not None:
            if not job.future.set_running_or_notify_cancel():
                continue  # cancelled while queued
            if self._cancel.is_set():  # closing: what is still queued is not started
                job.future.set_exception(CancelledError())
                continue
            try:
                job.future.set_result(job.solve())
            except BaseException as e:  # every outcome reaches the one waiting
                job.future.set_exception(e)

    @property
    def alive(self) -> bool:
        """Whether the thread still runs."""
        return self._thread.is_alive()

    @property
    def closing(self) -> bool:
        """Whether :meth:`close` was called (work in progress should end)."""
        return self._cancel.is_set()

    def close(self, timeout: float = 2.0) -> bool:
        """Cancel the solves (a running one ends at its next stage, queued ones at their
        first) and wait up to ``timeout`` s for the thread; whether it ended. Idempotent."""
        self._cancel.set()
        with self._lock:
            if not self._closed:
                self._closed = True
                self._jobs.put(None)
        self._thread.join(timeout)
        return not self._thread.is_alive()

    def __enter__(self) -> SolveWorker:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()


def run_solve(views: Sequence[Detections], board: Board, image_size: tuple[int, int],
              params: Mapping[str, Any], readiness: Readiness, *, worker: SolveWorker,
              stopping: threading.Event) -> SolveOutcome:
    """The node's solve: :func:`solve_views` on ``worker``'s thread, waiting for it unless
    ``stopping`` is set.

    On shutdown (``stopping`` set) the wait ends at once and the solve stops at its next
    stage; the worker's owner joins its thread (:meth:`SolveWorker.close`).

    Args:
        views: the kept views (all of one image size).
        board: the board.
        image_size: (width, height), pixels.
        params: validated parameters (camera_model, points, calibrate.*, max_views,
            output_file, ...).
        readiness: the collection's state, mentioned in the answer when not ideal.
        worker: the thread to solve on.
        stopping: set on shutdown; the wait then ends with success=false.

    Returns:
        success and the one-line summary, or success=false and the reason.
    """
    future = worker.submit(views, board, image_size, params, cancel=stopping)
    while not wait([future], timeout=0.1).done:
        if stopping.is_set():
            return SolveOutcome(False, "shutting down; calibration abandoned")
    try:
        run = future.result()
    except CancelledError:
        return SolveOutcome(False, "calibration failed: cancelled")
    except OutputError as unsaved:  # calibrated: the answer says so, the node publishes it
        return SolveOutcome(False, f"calibrated but NOT saved: {unsaved}; "
                            f"{unsaved.result.summary()}", unsaved.result)
    except ArtcalError as e:
        return SolveOutcome(False, f"calibration failed: {e}")
    except OSError as e:
        return SolveOutcome(False, "calibration failed: could not write "
                            f"{output_path(params)}: {e.strerror or e}")
    except Exception as e:
        return SolveOutcome(False, f"calibration failed: internal error: {e!r}")
    return SolveOutcome(True, solve_summary(run, readiness=readiness), run.result)


def queue_report(worker: SolveWorker, directory: Path, result: CalibrationResult,
                 views: Sequence[Detections], board: Board, *,
                 tone_curve: Mapping[str, Any] | None, board_check: Mapping[str, Any] | None,
                 title: str, said: Callable[[bool, str], object]) -> Path:
    """Write a solve's report into ``directory`` on the solve thread, behind the solves
    queued now (its plots take seconds: the caller answers first).

    ``said`` is called on that thread with (True, where it is) once written, or (False,
    why not); not at all when the worker closes first. Returns ``directory``.
    """
    from artcal_ros.core.calibrate.report import write_report

    def stop_when_closing(_page: str) -> None:
        if worker.closing:
            raise CancelledError

    def write() -> list[Path]:
        return write_report(directory, result, tone_curve=tone_curve, board_check=board_check,
                            detections=list(views), board=board, title=title,
                            progress=stop_when_closing)

    worker.submit_task(write).add_done_callback(report_said(directory, said))
    return directory


def report_said(directory: Path, said: Callable[[bool, str], object], *,
                stopped: tuple[type[BaseException], ...] = (CancelledError,)
                ) -> Callable[[Future[Any]], None]:
    """A done-callback for a report's future: ``said(True, where)`` once written,
    ``said(False, why not)`` on an error, nothing when it was cancelled or ended by one of
    ``stopped`` (its worker closing)."""
    def done(future: Future[Any]) -> None:
        error = None if future.cancelled() else future.exception()
        if future.cancelled() or isinstance(error, stopped):
            return
        if error is None:
            said(True, f"report written: {directory / 'report.pdf'}")
        else:
            said(False, f"no report in {directory}: {error}")

    return done
