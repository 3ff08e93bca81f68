"""Replay tests share the integration tier's DDS set-up: their own domain, this machine only."""

from __future__ import annotations

from test.integration.conftest import _stop_node_processes, probe

__all__ = ["_stop_node_processes", "probe"]
