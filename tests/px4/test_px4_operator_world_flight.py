"""Issue 35 on PX4 SITL (SIH quadrotor): a ground-station script on PX4's GCS link uploads a fence (an inclusion
polygon, three exclusion polygons, one concave, and a circle; PX4 enforces it at once) and a one-item mission;
``fuseplan fly --fence-from-vehicle --goal-from-vehicle --arm`` on the API/offboard link reads them (PX4 has no
home item: home is the scenario's), plans round them and flies there; the flown track keeps d_coll from every
zone (the report's telemetry clearance, and the track's positions checked here)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from operator_course import D_COLL, GOAL, POLYGONS, base_scenario, fence_items, goal_mission, track_clearance
from px4_harness import FAST
from statustext_gcs import StatusTextGcs, accepted_line

from companion.cli import main
from companion.mavlink.items import FENCE, MISSION
from companion.mavlink.link import Link
from companion.mavlink.protocol import MissionClient
from companion.mavlink.statustext import Severity
from planner.world.home import Home

HOME = Home(-35.363261, 149.165230, 584.0)


async def _upload(link: Link) -> None:
    client = MissionClient(link)
    await client.upload_verified(fence_items(HOME), FENCE)
    await client.upload_verified(goal_mission(HOME, home_item=False), MISSION)


# fuseplan serve's PX4 test flies the same course from the same operator's upload (fence and goal read from the
# vehicle, planned round, flown safe, the track checked zone by zone, the STATUSTEXT at the ground station)
@pytest.mark.slow(covered_by="px4/test_px4_serve.py::test_serve_on_px4_replaces_flies_and_survives_a_restart")
def test_px4_flies_round_the_fence_and_to_the_goal_the_operator_uploaded(px4_factory_fn, tmp_path: Path) -> None:
    scenario = base_scenario(tmp_path / "base.toml", HOME, "copter", 10.0)
    px4 = px4_factory_fn(HOME, speedup=FAST)
    report = tmp_path / "rep"
    # the ground station stays on PX4's GCS link through the flight: PX4 forwards the companion's STATUSTEXT to it
    with StatusTextGcs(f"udpout:127.0.0.1:{px4.gcs_port}", first=_upload) as gcs:
        code = main(["fly", str(scenario), "--connect", px4.companion_url, "--fence-from-vehicle",
                     "--goal-from-vehicle", "--arm", "--report", str(report), "-q"])
    flight = json.loads((report / "flight.json").read_text())
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    assert code == 0 and flight["completed"] is True and flight["flown_safe"] is True, flight
    world = next(e for e in events if e["event"] == "vehicle_world")
    assert len(world["zones"]) == len(POLYGONS) + 1 and world["goal"] is not None
    assert flight["fence_items"] == 0  # the operator's fence stays on the vehicle as it is
    assert flight["min_static_clearance_m"] >= D_COLL, flight
    flown = np.array([[e["x"], e["y"]] for e in events if e["event"] == "position"])
    assert len(flown) > 20
    gaps = track_clearance(flown)
    print(f"flown clearance {flight['min_static_clearance_m']:.1f} m ({flight.get('nearest_obstacle')}); "
          f"by zone {gaps}")
    assert min(gaps.values()) >= D_COLL, gaps
    assert np.hypot(*(flown[-1] - np.asarray(GOAL))) < 100.0  # it got there
    print(f"the ground station (streams off in {gcs.streams_off_s:.2f} s) heard:",
          *(f"{ln.severity} {ln.text}" for ln in gcs.from_companion()), sep="\n  ")
    said = [(ln.severity, ln.text) for ln in gcs.from_companion()]
    assert said[:2] == [(Severity.INFO, accepted_line(report)),
                        (Severity.INFO, "fuseplan: mission uploaded and verified")], gcs.lines
