"""Smoke test of bench/conversion.py: every encoding and format gives a complete row on a
small frame, and its grey is the frame's (no timing asserted: the machine is shared)."""

from __future__ import annotations

import math

import numpy as np

from bench import conversion


def test_conversion_rows_cover_every_case_and_get_the_grey_right() -> None:
    # a smooth colour frame, so demosaicing and jpeg err by little
    y, x = np.mgrid[0:48, 0:64] / 64.0
    bgr = np.dstack([40 + 60 * x, 120 + 80 * y, 220 - 90 * x * y]).round().astype(np.uint8)
    rows = conversion.run(bgr, repeats=1)
    names = conversion.RAW_ENCODINGS + conversion.COMPRESSED_FORMATS
    assert [r.encoding for r in rows] == names
    for r in rows:
        for ms in (r.image_ms, r.gray_ms, r.gray_via_image_ms, r.copy_ms):
            assert math.isfinite(ms) and ms >= 0, r
        if r.encoding in ("mono8", "bgr8", "rgb8", "rgba8", "bgra8", "mono16", "16UC1") \
                or "png" in r.encoding:
            assert r.gray_rms == 0, r  # lossless
        else:  # demosaicing, jpeg and yuv422's rounding, on a smooth frame
            assert 0 < r.gray_rms < 2, r
    by_name = {r.encoding: r for r in rows}
    assert by_name["bgr8"].mb == 48 * 64 * 3 / 1e6
    assert by_name["bayer_rggb16"].mb == 48 * 64 * 2 / 1e6
    text = conversion.table(rows)
    assert text.count("\n| `") == len(names)
