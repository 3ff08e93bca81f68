"""bench.paper --quick runs end to end: every study's table has its rows and columns, the
figures that cannot be missing are finite, and both plots are written."""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import pytest

from bench import paper
from bench.paper_jitter import METHODS as JITTER_METHODS
from bench.paper_sets import METRICS, POINTS
from bench.paper_table2 import METHODS


def test_quick_run_tables_and_plots(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert paper.main(["--quick", "--work", str(tmp_path), "--out", str(tmp_path)]) == 0
    printed = capsys.readouterr().out
    for title in ("## Table 2", "## Figure 5", "## Jitter"):
        assert title in printed
    results = json.loads((tmp_path / "paper_quick.json").read_text())
    plan = paper.QUICK

    rows = results["table2"]
    assert [(r["camera"], r["method"], r["board"]) for r in rows] == [
        (c, m, b) for c in plan.table2_cameras for m, b in METHODS]
    for r in rows:
        assert set(paper.TABLE2_COLUMNS) <= set(r)
        assert 0 <= r["found %"] <= 100 and r["points/frame"] >= 0
        if r["method"].startswith("ours") and r["board"] == "marker_grid":
            # our marker grid is found in these views and always gives a calibration
            assert all(math.isfinite(r[c]) for c in ("std", "max", "proj RMS", "proj max"))
    # one pose set: its rows are the table's
    assert [(r["camera"], r["method"]) for r in results["table2 per seed"]] == [
        (r["camera"], r["method"]) for r in rows]
    # a markdown row per method and camera
    assert printed.count("| ours corners | marker_grid |") == len(plan.table2_cameras)

    (sets,) = results["sets"]
    assert sets["camera"] == "webcam" and sets["sizes"] == list(plan.sizes)
    for p in POINTS:
        for m in METRICS:
            assert len(sets[f"{p} {m}"]) == len(plan.sizes)
            assert all(math.isfinite(v) and v > 0 for v in sets[f"{p} {m}"])

    jitter = results["jitter"]
    assert len(jitter) == len(plan.jitter_sizes)
    # the measured marker sides grow with the asked ones
    assert [r["size px"] for r in jitter] == sorted(r["size px"] for r in jitter)
    for r in jitter:
        for m in JITTER_METHODS[:2]:
            assert math.isfinite(r[f"{m} std"]) and math.isfinite(r[f"{m} bias"])

    for name in ("set_size.png", "jitter.png"):
        img = cv2.imread(str(tmp_path / name))
        assert img is not None and img.shape[1] == 1000
