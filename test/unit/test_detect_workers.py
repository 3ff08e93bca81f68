"""The detector works in a process forked after its parent detected (a multiprocessing pool's
worker): the kernel pool's threads do not survive a fork, so the child must not reuse it."""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import pytest

from artcal_ros import Board, detect
from artcal_ros.synth import Camera, Photometry, random_poses, render_view

BOARD = Board()


def _frame() -> np.ndarray:
    cam = Camera.preset("webcam")
    rng = np.random.default_rng(3)
    ((rvec, tvec),) = random_poses(BOARD, cam, 1, rng)
    return render_view(BOARD, cam, rvec, tvec, photometry=Photometry.clean(), rng=rng).image


def _markers(image: np.ndarray) -> int:
    return len(detect(image, BOARD))


@pytest.mark.skipif(not hasattr(os, "fork"), reason="fork is POSIX only")
def test_a_forked_worker_detects_after_its_parent_did(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ARTCAL_THREADS", "2")
    image = _frame()
    found = _markers(image)  # the parent's kernel pool and its threads now exist
    assert found > 50
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("fork")) as pool:
        child = pool.submit(_markers, image)
        try:
            in_child = child.result(timeout=120)
        finally:
            for process in list(getattr(pool, "_processes", {}).values()):
                if child.running():  # a hung worker would keep the pool from closing
                    process.kill()
    assert in_child == found
