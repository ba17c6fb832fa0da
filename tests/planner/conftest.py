"""Planner test fixtures: ``compiled``, the compiled cost kernel with its broad phase whatever the environment
says (the kernel tests use it with tests/kernel_reference.py)."""

from __future__ import annotations

import pytest

from planner import kernel


@pytest.fixture
def compiled(monkeypatch: pytest.MonkeyPatch) -> None:
    """The compiled kernel and its broad phase: their environment variables unset for the test."""
    monkeypatch.delenv(kernel.ENV_VAR, raising=False)
    monkeypatch.delenv(kernel.BROAD_ENV_VAR, raising=False)
    assert kernel.chosen() == "compiled" and kernel.broad_phase()
