"""Issue 35 on ArduPlane SITL: a ground-station script on SERIAL2 uploads a fence (an inclusion polygon, three
exclusion polygons, one concave, and a circle) and a one-item mission; ``fuseplan fly --fence-from-vehicle
--goal-from-vehicle --arm`` on SERIAL1 reads them, plans round them, flies there, and the flown track keeps d_coll
from every zone (the report's telemetry clearance, and the track's positions checked here)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from operator_course import D_COLL, POLYGONS, base_scenario, fence_items, goal_mission, track_clearance
from statustext_gcs import StatusTextGcs, accepted_line

from companion.cli import main
from companion.mavlink.items import FENCE, MISSION
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mavlink.statustext import Severity
from planner.world.home import Home

HOME = Home(-35.363261, 149.165230, 584.0)
FAST = 20.0


async def _upload(link: Link) -> None:
    client = MissionClient(link)
    await client.upload_verified(fence_items(HOME), FENCE)
    await client.upload_verified(goal_mission(HOME, home_item=True), MISSION)


# fuseplan serve's ArduPlane test flies the same course from the same operator's upload (fence and goal read from
# the vehicle, planned round, flown safe, the track checked zone by zone, the STATUSTEXT at the ground station);
# fly's own lines on the wire are test_announce's
@pytest.mark.slow(covered_by="sitl/test_serve_arduplane.py::test_serve_on_arduplane_replaces_flies_and_survives_a_reboot")
def test_arduplane_flies_round_the_fence_and_to_the_goal_the_operator_uploaded(sitl_factory_fn,
                                                                                tmp_path: Path) -> None:
    scenario = base_scenario(tmp_path / "base.toml", HOME, "plane", 18.0)
    sitl = sitl_factory_fn("plane", HOME, speedup=FAST)
    report = tmp_path / "rep"
    # the ground station stays on SERIAL2 through the flight: ArduPilot routes the companion's STATUSTEXT to it
    with sitl.hold_serial0(), StatusTextGcs(sitl.serial2_url, first=_upload) as gcs:
        code = main(["fly", str(scenario), "--connect", sitl.serial1_url, "--fence-from-vehicle",
                     "--goal-from-vehicle", "--arm", "--report", str(report), "-q"])
    flight = json.loads((report / "flight.json").read_text())
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    assert code == 0 and flight["completed"] is True and flight["flown_safe"] is True, flight
    world = next(e for e in events if e["event"] == "vehicle_world")
    assert len(world["zones"]) == len(POLYGONS) + 1 and world["goal"] is not None
    assert flight["fence_items"] == 0  # the operator's fence stays on the vehicle as it is
    # the report's clearance is the telemetry track's, against every zone (prisms and the circle)
    assert flight["track_source"] == "GLOBAL_POSITION_INT" and flight["min_static_clearance_m"] >= D_COLL, flight
    flown = np.array([[e["x"], e["y"]] for e in events if e["event"] == "position"])
    assert len(flown) > 20
    gaps = track_clearance(flown)
    nearest = flight.get("nearest_obstacle")
    print(f"flown clearance {flight['min_static_clearance_m']:.1f} m ({nearest}); by zone {gaps}")
    assert min(gaps.values()) >= D_COLL, gaps
    assert np.hypot(*(flown[-1] - [1180.0, 720.0])) < 200.0  # it got there
    print(f"the ground station (streams off in {gcs.streams_off_s:.2f} s) heard:",
          *(f"{ln.severity} {ln.text}" for ln in gcs.from_companion()), sep="\n  ")
    said = [(ln.system, ln.severity, ln.text) for ln in gcs.from_companion()]
    assert said[:2] == [(1, Severity.INFO, accepted_line(report)),
                        (1, Severity.INFO, "fuseplan: mission uploaded and verified")], gcs.lines
