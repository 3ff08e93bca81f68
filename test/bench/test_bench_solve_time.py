"""Smoke test of bench/solve_time.py: its core functions run on a tiny case and give
complete rows with finite positive times (no timing assertions: the machine is shared)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from bench import solve_time


def _finite_positive(value: float) -> bool:
    return isinstance(value, float) and math.isfinite(value) and value > 0


def test_solve_time_rows_are_complete_for_ten_webcam_views() -> None:
    # max_views 6 < 10 views: both settings are solved (selection included), not reused.
    rows = solve_time.solve_time_rows(("webcam",), (10,), repeats=1, max_views=6,
                                      log=lambda _line: None)
    keys = {(r["points"], r["setting"]) for r in rows}
    assert keys == {(p, s) for p in solve_time.POINTS for s in ("all", "default")}
    for r in rows:
        assert "error" not in r, r
        assert r["preset"] == "webcam" and r["views"] == 10
        assert _finite_positive(r["wall_s"]) and _finite_positive(r["cpu_s"]), r
        assert len(r["walls_s"]) == 1 and all(_finite_positive(w) for w in r["walls_s"])
        assert r["views_used"] == (10 if r["setting"] == "all" else 6)
        assert _finite_positive(r["rms_px"]) and _finite_positive(r["max_px"])
    table = solve_time.markdown_grid(rows, 6)
    assert table.count("\n") == 1 + len(solve_time.POINTS)  # header, rule, one line a mode
    image = solve_time.plot_solve_time(rows, 6)
    assert image.ndim == 3 and image.shape[2] == 3 and image.dtype == np.uint8


def test_session_rows_time_the_node_path_and_write_its_yaml(tmp_path: Path) -> None:
    rows = solve_time.session_rows(("webcam",), (6,), views=10, seeds=(solve_time.SEED,),
                                   points=("corners",), output_dir=tmp_path,
                                   log=lambda _line: None)
    assert len(rows) == 1
    r = rows[0]
    assert "error" not in r, r
    assert r["sets"] == 1 and r["max_views"] == 6
    assert _finite_positive(r["wall_s"]) and _finite_positive(r["cpu_s"])
    assert _finite_positive(r["rms_px"])
    assert len(r["rms_sets_px"]) == 1 and _finite_positive(r["rms_sets_px"][0])
    assert (tmp_path / "webcam_corners_6.yaml").is_file()
    # The row is its own reference: the paired ratio is exactly 1.
    assert "| 1.00 |" in solve_time.markdown_session(rows, 6)


def test_profile_breakdown_accounts_for_the_whole_solve() -> None:
    prof = solve_time.profile_case("webcam", "centers", 8, 6, top=5)
    stages = dict(prof["stages"])
    assert _finite_positive(prof["total_s"])
    assert all(math.isfinite(s) and s >= 0 for s in stages.values())
    assert stages["cross-validation (5 folds)"] > 0
    assert sum(stages.values()) >= 0.99 * prof["total_s"]
    assert len(prof["top"]) == 5
