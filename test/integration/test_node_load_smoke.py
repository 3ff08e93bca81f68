"""bench.node_load's core against the real node over DDS, briefly: the result is complete.

Only completeness is checked (frames went out, the node saw them, an overlay came back,
memory was sampled, ~/calibrate answered, SIGINT stopped the node): the bench's figures
depend on the machine's load, so no timing or rate is asserted here.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.node_load import LoadSpec, run_load

pytestmark = pytest.mark.integration


def test_node_load_smoke(tmp_path: Path) -> None:
    # 320 x 240 keeps rendering and detection short; two views are enough to cycle.
    spec = LoadSpec(320, 240, rate_hz=10.0, seconds=3.0, views=2, baseline=False,
                    node_name="load_smoke_calibrator")
    # Generous waits: on a busy 2-core machine discovery alone can take several seconds,
    # and a frame's detection a few more.
    result = run_load(spec, tmp_path, discovery_timeout=60.0, drain_timeout=90.0,
                      log=lambda _: None)
    logs = "\n".join(f"--- {p.name}\n{p.read_text(errors='replace')[-2000:]}"
                     for p in sorted(tmp_path.glob("*.log")))
    assert not result.error, f"{result.error}\n{logs}"
    assert result.sent > 0, logs
    assert (result.count("frames seen") or 0) > 0, f"{result.diagnostics}\n{logs}"
    assert (result.count("frames processed") or 0) > 0, f"{result.diagnostics}\n{logs}"
    assert result.overlays_reliable >= 1, logs
    assert result.latency and result.overlay_size == (320, 240), logs
    assert result.rss_kb and all(kb > 0 for _, kb in result.rss_kb), logs
    assert result.calibrate_s is not None and result.calibrate_message, result.calibrate_message
    assert not result.node_killed, logs
    assert result.node_exit in (0, -2, 130), logs
