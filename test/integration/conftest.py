"""Integration tests run on their own DDS domain, on this machine only (see ros_harness)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from test.integration.frames import CalibrationBag, calibration_bag
from test.integration.ros_harness import Probe, configure_ros_env, crashed_nodes, stop_all

configure_ros_env()


@pytest.fixture(scope="session")
def probe() -> Iterator[Probe]:
    """One probe node for the session (creating DDS participants costs time)."""
    p = Probe()
    yield p
    p.close()


@pytest.fixture(autouse=True)
def _stop_node_processes() -> Iterator[None]:
    """No node outlives its test, even a failed one; none of them wrote a traceback."""
    yield
    stop_all()
    crashed = crashed_nodes()
    assert not crashed, "a node wrote a traceback:\n" + "\n".join(crashed)


@pytest.fixture(scope="session")
def bag(tmp_path_factory: pytest.TempPathFactory) -> CalibrationBag:
    """Board frames with the camera that took them (bags/sample, or rendered)."""
    return calibration_bag(tmp_path_factory.mktemp("bag"))
