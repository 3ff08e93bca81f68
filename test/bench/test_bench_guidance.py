"""Smoke test of bench/guidance.py: one short session of each strategy runs and gives
complete figures (no accuracy or timing assertions: the benchmark measures those)."""

from __future__ import annotations

import math

import numpy as np

from bench import guidance


def test_one_short_session_of_each_strategy_gives_complete_rows() -> None:
    result = guidance.run(("webcam",), 1, 5, log=lambda _line: None)
    r = result["cases"]["webcam, default board"]
    for strategy in guidance.STRATEGIES:
        (session,) = r["sessions"][strategy]
        d = session["difference_px"]
        u = session["uncertainty_px"]
        assert len(d) == len(u) == 5
        # no figure before the first solve, one after every view from then on
        first = guidance.SOLVE_VIEWS - 1
        assert all(math.isnan(x) for x in d[:first])
        assert all(math.isfinite(x) and x > 0 for x in d[first:])
        assert all(math.isfinite(x) and x > 0 for x in u[first:])
        for name, _ in guidance.MEASURES:
            (views,) = r["views"][strategy][name]
            assert views is None or guidance.SOLVE_VIEWS <= views <= 5
    assert math.isfinite(r["next_pose_s_at_40"]) and r["next_pose_s_at_40"] > 0
    table = guidance.markdown(result)
    assert table.count("\n| webcam, default board |") == len(guidance.STRATEGIES)
    differences = guidance.markdown_differences(result, at=(4, 5))
    assert differences.count("\n| webcam, default board |") == len(guidance.STRATEGIES)


def test_the_same_seed_starts_every_strategy_from_the_same_views() -> None:
    # sessions of only the shared start views (as many as a solve needs, so that they are solved)
    first = {s: guidance.run_session("webcam", s, guidance.SEED, guidance.SOLVE_VIEWS,
                                     start_views=guidance.SOLVE_VIEWS)
             for s in guidance.STRATEGIES}
    values = {s: first[s].difference_px[-1] for s in guidance.STRATEGIES}
    assert all(math.isfinite(v) for v in values.values()), values
    assert len(set(values.values())) == 1, values


def test_bars_parameters_of_a_centred_fronto_parallel_board() -> None:
    w, h = 640, 480
    obj = guidance.BOARD.object_corners().reshape(-1, 3)
    # the board's image: a scaled copy centred in the image, every point in view
    x0, y0, x1, y1 = guidance.BOARD.extent_m
    scale = 0.5 * w / (x1 - x0)
    px = (obj[:, :2] - [(x0 + x1) / 2, (y0 + y1) / 2]) * scale + [(w - 1) / 2, (h - 1) / 2]
    x, y, size, skew = guidance.bars_parameters(guidance.BOARD, px, np.ones(len(obj), bool),
                                                (w, h))
    assert abs(x - 0.5) < 0.02 and abs(y - 0.5) < 0.02
    area = (0.5 * w) * (0.5 * w * (y1 - y0) / (x1 - x0))
    assert math.isclose(size, math.sqrt(area / (w * h)), rel_tol=0.02)
    assert skew < 1e-6
