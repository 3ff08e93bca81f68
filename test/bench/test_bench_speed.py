"""The speed benchmark's core runs end to end on a tiny frame set (no timing asserted)."""

from __future__ import annotations

import math
from pathlib import Path

import cv2

from bench import speed


def test_speed_table_rows_and_plot(tmp_path: Path) -> None:
    rows = speed.run(["640x480"], 3, [1], empty=False)
    assert [(r.frames, r.threads) for r in rows] == [("640x480", 1)]
    for r in rows:
        for ms in (r.cold_ms, r.stream_ms, r.tracked_ms, r.opencv_ms):
            assert math.isfinite(ms) and ms >= 0
        assert r.cold_ms > 0 and r.opencv_ms > 0
        assert r.markers > 0
        # against the renderer's truth: our corners well inside OpenCV's error
        assert r.corner_rms_px < r.opencv_rms_px
    text = speed.table(rows)
    assert text.count("\n| 640x480 | 1 |") == 1
    out = tmp_path / "speed.png"
    speed.plot(rows, out, 1)
    img = cv2.imread(str(out))
    assert img is not None and img.shape[2] == 3
