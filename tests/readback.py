"""Comparing missions in tests as an ArduPilot vehicle stores them (the built-in simulator stores items as the
plane or the copter does: companion.mavlink.storage), when a test does not care which vehicle it flew."""

from __future__ import annotations

from collections.abc import Sequence

from companion.mavlink.items import MissionItem, compare_items
from companion.mavlink.storage import Firmware, mission_difference, stored

ARDUPILOT = (Firmware.ARDUPLANE, Firmware.ARDUCOPTER)


def same_item(sent: MissionItem, got: MissionItem) -> bool:
    """``got`` is ``sent`` as ArduPlane or ArduCopter stores it."""
    return any(compare_items(stored(sent, f), stored(got, f)) is None for f in ARDUPILOT)


def same_mission(a: Sequence[MissionItem], b: Sequence[MissionItem]) -> bool:
    """Equal missions as ArduPlane or ArduCopter stores them, item 0 (ArduPilot's home) aside."""
    return any(mission_difference(a, b, firmware=f) is None for f in ARDUPILOT)
