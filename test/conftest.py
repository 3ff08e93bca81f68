"""Shared pytest fixtures and paths."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PARAMS_FILE = ROOT / "config" / "calibrator.yaml"
SAMPLE_BAG = ROOT / "bags" / "sample"


@pytest.fixture
def params_file() -> Path:
    return PARAMS_FILE
