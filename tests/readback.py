"""Comparing missions in tests as an ArduPilot vehicle stores them (the built-in simulator stores items as the
plane or the copter does: companion.mavlink.storage), when a test does not care which vehicle it flew."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from pymavlink import mavwp

from companion.mavlink.items import MISSION, MissionItem, compare_items
from companion.mavlink.link import MAV_COMP_ID_ONBOARD_COMPUTER, Link
from companion.mavlink.protocol import MissionClient
from companion.mavlink.storage import Firmware, mission_difference, stored

ARDUPILOT = (Firmware.ARDUPLANE, Firmware.ARDUCOPTER)


def same_item(sent: MissionItem, got: MissionItem) -> bool:
    """``got`` is ``sent`` as ArduPlane or ArduCopter stores it."""
    return any(compare_items(stored(sent, f), stored(got, f)) is None for f in ARDUPILOT)


def same_mission(a: Sequence[MissionItem], b: Sequence[MissionItem]) -> bool:
    """Equal missions as ArduPlane or ArduCopter stores them, item 0 (ArduPilot's home) aside."""
    return any(mission_difference(a, b, firmware=f) is None for f in ARDUPILOT)


def waypoints_file(path: Path) -> list[MissionItem]:
    """A QGC WPL 110 file as MAVProxy loads it (pymavlink's mavwp), as mission items."""
    loader = mavwp.MAVWPLoader()
    loader.load(str(path))
    return [MissionItem.from_message(loader.wp(k)) for k in range(loader.count())]


async def vehicle_mission(url: str) -> list[MissionItem]:
    """The vehicle's mission, downloaded over a link of its own (another onboard component than fly's)."""
    async with Link(url, source_component=MAV_COMP_ID_ONBOARD_COMPUTER + 1, open_timeout=5.0) as link:
        await link.wait_heartbeat(timeout=10.0)
        return await MissionClient(link).download(MISSION)


def first_difference(a: Sequence[MissionItem], b: Sequence[MissionItem]) -> tuple | None:
    """The first pair of items (item 0, ArduPilot's home, aside) that :func:`same_item` tells apart, or the lengths
    if they differ; None when the missions are the same item by item."""
    if len(a) != len(b):
        return len(a), len(b)
    return next(((x, y) for x, y in zip(a[1:], b[1:]) if not same_item(x, y)), None)
