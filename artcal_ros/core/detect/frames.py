"""Every frame of a recording detected on worker processes, as one streamed Detector would.

Offline (``artcal calibrate`` reading a bag or a folder) the frames are independent, but a
:class:`~artcal_ros.core.detect.Detector` learns the lens and the tone curve from the frames
before. So the first ``warmup`` frames are detected here, in order, by the caller's detector;
the rest go in runs of ``run`` consecutive frames to forked worker processes, each run
detected in order by a detector that starts from what the caller's learnt in the warm-up.
A frame's result then depends only on the frames before it (the warm-up and its run), not
on how many workers there are or which one took its run: one worker gives the same results.
"""

from __future__ import annotations

import itertools
import multiprocessing
import os
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor

import numpy as np

from artcal_ros.core.board import Board
from artcal_ros.core.detect.detector import Detector, DetectorConfig
from artcal_ros.core.detect.image import to_gray
from artcal_ros.core.detect.lens import LensPoolState
from artcal_ros.core.detect.tone import ToneState
from artcal_ros.core.detections import Detections

__all__ = ["default_workers", "detect_frames"]

WARMUP = 8  # frames the caller's detector learns from before the runs start
RUN = 16  # consecutive frames one worker detects from the warm-up's state

Frame = tuple[str, np.ndarray]  # (source name, image)
State = tuple[LensPoolState, ToneState]  # a Detector's snapshot

_WORKER: list[Detector] = []  # the worker process's detector (empty in the caller)


def default_workers() -> int:
    """Processes to detect on: one per CPU this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def _start_worker(board: Board, config: DetectorConfig) -> None:
    # one process per core already: a worker's kernels use one thread. (OpenCV's are left
    # alone: cv2.setNumThreads in a forked child can wait forever on its parent's pool.)
    os.environ["ARTCAL_THREADS"] = "1"
    _WORKER.append(Detector(board, config))


def _detect_run(detector: Detector, state: State, run: list[Frame]) -> list[Detections]:
    """The frames of ``run`` in order, by ``detector`` set back to ``state`` first."""
    detector.restore(state)
    return [detector.detect(image, source=source) for source, image in run]


def _worker_run(state: State, run: list[Frame]) -> list[Detections]:
    return _detect_run(_WORKER[0], state, run)


def detect_frames(frames: Iterable[Frame], detector: Detector, *, workers: int = 0,
                  warmup: int = WARMUP, run: int = RUN) -> Iterator[Detections]:
    """The Detections of every frame, in the frames' order.

    Args:
        frames: (source name, image) pairs of one camera; images as
            :meth:`Detector.detect` takes them. Read as the workers need them (a few runs
            ahead), so a long recording is never held in memory.
        detector: detects the warm-up frames (and keeps what it learnt from them: its
            ``tone`` afterwards is theirs); the workers' detectors share its board and
            configuration.
        workers: processes (0: :func:`default_workers`); 1, or no ``fork`` on this
            platform, detects every run in this process, with the same results.
        warmup, run: see the module docstring.
    """
    frames = iter(frames)
    for source, image in itertools.islice(frames, warmup):
        yield detector.detect(image, source=source)
    state = detector.snapshot()
    # (grey before it travels: a third of a colour frame to copy and hold; the detector's
    # first step anyway)
    runs = iter(lambda: [(source, to_gray(image))
                         for source, image in itertools.islice(frames, max(1, run))], [])
    first = list(itertools.islice(runs, 2))
    workers = workers if workers > 0 else default_workers()
    if (len(first) < 2 or workers <= 1
            or "fork" not in multiprocessing.get_all_start_methods()):
        local = Detector(detector.board, detector.config)
        for frames_run in itertools.chain(first, runs):
            yield from _detect_run(local, state, frames_run)
        return
    # fork: the workers start from this process's loaded kernels, nothing is pickled but
    # the runs and their results
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("fork"),
                               initializer=_start_worker,
                               initargs=(detector.board, detector.config))
    try:
        pending: deque[Future[list[Detections]]] = deque()
        for frames_run in itertools.chain(first, runs):
            pending.append(pool.submit(_worker_run, state, frames_run))
            if len(pending) > workers:  # a run waiting for each worker, no more in memory
                yield from pending.popleft().result()
        while pending:
            yield from pending.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
