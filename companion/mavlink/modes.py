"""Flight-mode numbers from HEARTBEAT fields alone: lookups in the autopilot's profile (:mod:`companion.mavlink.profiles`,
which holds the tables), for callers that have a HEARTBEAT but no link (the simulator's traffic feed)."""

from __future__ import annotations

from companion.mavlink.profiles import profile_for


def mode_number(autopilot: int, vehicle_type: int, name: str) -> int:
    """custom_mode for a mode name on this autopilot and vehicle type."""
    return profile_for(autopilot, vehicle_type).mode_number(name)

