"""Comparing missions in tests as an ArduPilot vehicle stores them (the built-in simulator stores items as the
plane or the copter does: companion.mavlink.storage), when a test does not care which vehicle it flew."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Sequence
from pathlib import Path

import pytest
from pymavlink import mavutil, mavwp

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


def tlog_messages(path: Path) -> list:
    """Every message of a .tlog, read by pymavlink as MAVProxy's logs are."""
    log = mavutil.mavlink_connection(str(path))
    out = []
    while (msg := log.recv_match()) is not None:
        if msg.get_type() != "BAD_DATA":
            out.append(msg)
    log.close()
    return out


def mavlogdump() -> list[str]:
    """The command that runs pymavlink's mavlogdump.py (the test skips where it is not installed)."""
    script = shutil.which("mavlogdump.py")
    if script is None:
        pytest.skip("mavlogdump.py (installed with pymavlink) is not on PATH")
    return [sys.executable, script]


def assert_the_tlog_holds_the_flight(report: Path) -> None:
    """The report's flight.tlog read back by pymavlink (times that never go backwards, HEARTBEATs both ways: ours
    from the onboard computer's component, link 3 as MAVProxy marks what it sends) and by mavlogdump.py: the
    MISSION_ITEM_INTs we sent, the last of each seq, are the report's mission.waypoints (the mission that flew: a
    replan's items sent again replace the first upload's)."""
    mission = waypoints_file(report / "mission.waypoints")
    msgs = tlog_messages(report / "flight.tlog")
    times = [m._timestamp for m in msgs]
    assert len(msgs) > 500 and times == sorted(times) and times[-1] - times[0] > 2.0
    ours = (1, MAV_COMP_ID_ONBOARD_COMPUTER)
    beats = [((m.get_srcSystem(), m.get_srcComponent()), m._link) for m in msgs if m.get_type() == "HEARTBEAT"]
    assert (ours, 3) in beats and ((1, 1), 0) in beats  # ours, sent; the autopilot's, received
    sent = [m for m in msgs if m.get_type() == "MISSION_ITEM_INT" and m.mission_type == MISSION
            and (m.get_srcSystem(), m.get_srcComponent()) == ours]
    uploaded = {m.seq: MissionItem.from_message(m) for m in sent}  # an item asked for twice is sent twice
    assert sorted(uploaded) == list(range(len(mission)))
    assert all(same_item(uploaded[it.seq], it) for it in mission[1:])  # item 0 is home in the file too

    dump = subprocess.run([*mavlogdump(), "--format", "json", "--types", "MISSION_ITEM_INT",
                           str(report / "flight.tlog")], capture_output=True, text=True, timeout=60, check=True)
    rows = [json.loads(line) for line in dump.stdout.splitlines() if line.startswith("{")]
    # ours go to the autopilot (component 1); the vehicle's (its readback) come to us
    to_vehicle = {r["data"]["seq"]: r["data"] for r in rows
                  if r["data"]["target_component"] == 1 and r["data"]["mission_type"] == MISSION}
    assert sorted(to_vehicle) == list(range(len(mission)))
    for it in mission:
        row = to_vehicle[it.seq]
        assert (row["command"], row["x"], row["y"]) == (it.command, it.x, it.y), (it, row)
        assert abs(row["z"] - it.z) < 1e-3
    stamps = [r["meta"]["timestamp"] for r in rows]
    assert stamps == sorted(stamps)
