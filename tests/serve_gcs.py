"""A ground-station script for the ``fuseplan serve`` tests: our Link as system 255 / component 190 on another port
of the autopilot (or the simulator's one TCP port), uploading the operator's fence and mission and reading the
companion's STATUSTEXT lines; and the service's configuration file."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import gcs_world
import numpy as np
from operator_course import D_COLL, GOAL, POLYGONS, track_clearance
from pymavlink.dialects.v20 import common as mavlink

from companion.flight.supervisor import FlightSupervisor
from companion.mavlink.errors import CompanionError
from companion.mavlink.items import FENCE, MISSION, MissionItem
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mavlink.statustext import Reassembler
from companion.mission.events import EventLog
from companion.service import MAV_COMP_ID_PATHPLANNER, Handled, Service
from companion.service.serve import mission_key
from planner.world.home import Home


def two_item_mission(home: Home, home_item: bool, east: float, north: float, alt: float = 60.0) -> list[MissionItem]:
    """A takeoff and the goal (``east``, ``north`` metres from home), as an operator plans it in a ground station;
    on ArduPilot after the home placeholder at item 0."""
    items = gcs_world.goal_mission(home, north=north, east=east, alt=alt, home_item=home_item)
    takeoff = MissionItem(0, gcs_world.REL_INT, mavlink.MAV_CMD_NAV_TAKEOFF, x=items[-1].x,
                          y=items[-1].y, z=alt)
    items.insert(len(items) - 1, takeoff)
    return [it.with_seq(k) for k, it in enumerate(items)]


def write_config(path: Path, url: str, scenario: Path, log_folder: Path, poll_s: float = 2.0,
                 budget_s: float = 1.0, zones: Sequence[Path] = ()) -> Path:
    path.write_text(f"""[link]
url = "{url}"
heartbeat_timeout = 3.0
[plan]
scenario = "{scenario}"
zones = [{", ".join(f'"{z}"' for z in zones)}]
seed = 1
budget_s = {budget_s}
[service]
log_folder = "{log_folder}"
poll_s = {poll_s}
""")
    return path


class GroundStation:
    """The operator's ground station: uploads, and every whole STATUSTEXT line of the companion (component 195)
    with the wall time it came."""

    def __init__(self, url: str) -> None:
        self.link = Link(url, source_system=255, source_component=190, open_timeout=10.0)
        self.lines: list[tuple[float, str]] = []
        self._task: asyncio.Task | None = None

    async def __aenter__(self) -> GroundStation:
        await self.link.open()
        self.client = MissionClient(self.link)
        self._task = asyncio.create_task(self._listen())
        return self

    async def __aexit__(self, *exc: object) -> None:
        if self._task is not None:
            self._task.cancel()
            await asyncio.gather(self._task, return_exceptions=True)
        await self.link.close()

    async def _listen(self) -> None:
        joiner = Reassembler()
        async for msg in self.link.messages("STATUSTEXT", any_source=True):
            if msg.get_srcComponent() == MAV_COMP_ID_PATHPLANNER:
                line = joiner.feed(msg)
                if line is not None:
                    self.lines.append((time.monotonic(), line))

    async def upload(self, mission: Sequence[MissionItem], fence: Sequence[MissionItem] | None = None) -> float:
        """Fence (if any), then mission, each verified; returns time.monotonic() when the mission was stored."""
        for items, kind in ((fence, FENCE), (mission, MISSION)):
            for attempt in range(3):  # as a ground station retries: PX4 under load fails a transfer now and then
                if items is None:
                    break
                try:
                    await self.client.upload_verified(items, kind)
                    break
                except CompanionError:
                    if attempt == 2:
                        raise
                    await asyncio.sleep(0.5)
        return time.monotonic()

    async def arm_and_start(self, ready_timeout: float = 90.0) -> None:
        """What the pilot does at the ground station: wait until the vehicle is ready, then its autopilot's own
        start sequence (ArduPlane AUTO, arm, start; PX4 arm, mission mode, start) from the first item."""
        sup = FlightSupervisor(self.link, self.client, EventLog(), arm=True)
        await sup.wait_ready(ready_timeout)
        await sup.start(1 if self.client.home_at_zero(MISSION) else 0)

    async def line(self, match: Callable[[str], bool], after: float, timeout: float) -> tuple[float, str]:
        """The first companion line since ``after`` that matches."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            for t, text in self.lines:
                if t >= after and match(text):
                    return t, text
            await asyncio.sleep(0.05)
        raise AssertionError(f"no matching STATUSTEXT within {timeout:g} s; lines: {[s for _, s in self.lines]}")


async def verdict(service: Service, n: int) -> Handled:
    """Request ``n`` (from 0) once decided (the route is read back once more after the line)."""
    for _ in range(100):
        if len(service.handled) > n and service.handled[n].verdict:
            return service.handled[n]
        await asyncio.sleep(0.05)
    raise AssertionError(f"request {n + 1} undecided: {service.handled}")


async def replaced(gcs: GroundStation, service: Service, mission: list, fence: list | None,
                   home_at_zero: bool) -> dict[str, float]:
    """Upload; wait for the companion's line; check the vehicle holds the route (``home_at_zero``: ArduPilot's
    item 0). The times after the upload."""
    n = len(service.handled)
    stored = await gcs.upload(mission, fence)
    t_line, text = await gcs.line(lambda s: "uploaded and verified" in s, stored, 20.0)
    _, accepted = await gcs.line(lambda s: "plan accepted" in s, stored, 1.0)
    handled = await verdict(service, n)
    assert handled.verdict == "accepted", handled
    got = await gcs.client.download(MISSION)
    assert mission_key(got, home_at_zero) != mission_key(mission, home_at_zero) and len(got) > len(mission)
    times = {"replaced_s": round(handled.done_at - stored, 2), "told_s": round(t_line - stored, 2)}
    print(f"{times} {accepted!r} {text!r}")
    return times


def flown_round_the_zones(report: Path, goal_within_m: float) -> None:
    """As the operator-world flight checks it: the fence's five zones read from the vehicle, no fence uploaded,
    the telemetry track clear of every zone by d_coll (the polygons and the circle, checked here independently),
    and the goal reached."""
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    world = next(e for e in events if e["event"] == "vehicle_world")
    assert len(world["zones"]) == len(POLYGONS) + 1 and world["goal"] is not None
    flight = json.loads((report / "flight.json").read_text())
    assert flight["fence_items"] == 0 and flight["track_source"] == "GLOBAL_POSITION_INT"
    flown = np.array([[e["x"], e["y"]] for e in events if e["event"] == "position"])
    assert len(flown) > 20
    gaps = track_clearance(flown)
    print(f"by zone {gaps}")
    assert min(gaps.values()) >= D_COLL, gaps
    assert np.hypot(*(flown[-1] - np.asarray(GOAL))) < goal_within_m  # it got there
