"""The exposure sweep's core runs end to end on two steps of one pose."""

from __future__ import annotations

import numpy as np

from bench import exposure


def test_exposure_sweep_steps_table_and_plot() -> None:
    ex = exposure.exposures()
    assert len(ex) == exposure.STEPS == 16
    assert ex[0] == exposure.EXPOSURE_MIN and np.isclose(ex[-1], exposure.EXPOSURE_MAX)
    # nominal exposure, and one where the paper is clipped 7 times over
    steps = exposure.run("webcam", 1, only=[8, 14])
    nominal, clipped = steps[8], steps[14]
    for s in (nominal, clipped):
        assert s.wanted > 100
        assert s.decoded >= 0.5 * s.wanted
    # against the renderer's truth: ours well inside OpenCV's error at nominal exposure
    assert nominal.rms("centres") < 0.05 < nominal.rms("opencv centres")
    assert nominal.rms("corners") < 0.05 < nominal.rms("opencv corners")
    # clipped: OpenCV reads (almost) nothing; ours a few tenths of a pixel at most
    assert clipped.decoded_cv < 0.1 * clipped.wanted
    assert clipped.rms("centres") < 0.4
    text = exposure.table(steps)
    assert text.count("\n| ") == 16   # a row per step, the skipped ones empty
    img = exposure.plot(steps, "test")
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8
