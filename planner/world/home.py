"""The scenario's home: the origin of the local ENU frame every planner coordinate is in (docs/method.md §1)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Home:
    """Origin of the local ENU frame."""

    lat: float  # degrees
    lon: float  # degrees
    alt: float  # metres AMSL
