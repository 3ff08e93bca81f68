"""bench.flood, short: 3840x2160 mono8 at 60 Hz for 10 s into the real node.

No timing is asserted tightly (a busy 2-core machine): every ~/calibrate call is answered
within a generous bound, memory during the flood stays within a generous bound of what it
was before it and does not keep climbing, frames are processed again after the flood, and
the node exits 0 on SIGINT. The 2-minute figures are in docs/reliability.md.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from bench.flood import LARGE_SHM, FloodSpec, run_flood

pytestmark = pytest.mark.integration

ANSWER_BOUND_S = 10.0  # generous: the contract figure is 2 s, on an idle machine
RSS_GROWTH_MB = 1024.0  # over the flood, against the calm stream before it


@pytest.fixture
def large_shm() -> Iterator[None]:
    # Read by Fast DDS when a participant is created: the node and the publishers are new
    # processes; this process's listener is a new participant too.
    old = os.environ.get("FASTDDS_DEFAULT_PROFILES_FILE")
    os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = str(LARGE_SHM)
    yield
    if old is None:
        del os.environ["FASTDDS_DEFAULT_PROFILES_FILE"]
    else:
        os.environ["FASTDDS_DEFAULT_PROFILES_FILE"] = old


def test_flood_smoke(tmp_path: Path, large_shm: None) -> None:
    spec = FloodSpec(flood_s=10.0, calm_s=5.0, calm_rate_hz=1.0, call_every_s=1.0, views=2,
                     render_downscale=4, node_name="flood_smoke_calibrator")
    result = run_flood(spec, tmp_path, log=lambda _: None)
    log = result.node_log[-3000:]
    assert not result.error, f"{result.error}\n{log}"
    before, flood, after = result.phases
    assert flood.sent > 100, f"only {flood.sent} frames sent"
    assert flood.seen > 0 and flood.processed > 0, log
    answers = [a for p in result.phases for a in p.answers_s]
    assert answers and not any(p.unanswered for p in result.phases), log
    assert max(answers) < ANSWER_BOUND_S, f"slowest answer {max(answers):.1f} s"
    base = before.rss_mb()[1]
    peak = max(flood.rss_mb()[1], after.rss_mb()[1])
    assert peak - base < RSS_GROWTH_MB, f"VmRSS {base:.0f} MB before, {peak:.0f} MB peak"
    assert after.processed > 0, "no frame processed after the flood"
    assert result.node_exit == 0, log
    assert "Traceback" not in result.node_log, log
