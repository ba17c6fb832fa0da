"""Shared fixtures: paths to the shipped scenarios."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SCENARIOS = ROOT / "sitl_scenarios"


@pytest.fixture
def rescue_static() -> Path:
    return SCENARIOS / "rescue_static.toml"
